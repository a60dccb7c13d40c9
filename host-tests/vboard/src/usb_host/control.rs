//! Control transfers on EP0: the requests (what each one is for, its SETUP packet), the script
//! the enumeration runs (with the cdc-acm class requests, SET_LINE_CODING and
//! SET_CONTROL_LINE_STATE), the SETUP / data / status stages of a transfer, and what the host
//! does with each reply.

use super::descriptors::{
    check_bos, find_cdc, parse_bos_header, parse_configuration, parse_configuration_header, parse_device, parse_device_prefix,
    parse_langid, parse_string,
};
use super::{txn_s, Host, Next, CONTROL_GAP_S, CONTROL_TIMEOUT_S, RECOVERY_S, SET_ADDRESS_WAIT_S};
use crate::periph::usbd::{Handshake, Phy, Usbd};

/// What a control transfer is for.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum Tag {
    Device64,
    SetAddress(u8),
    Device18,
    Bos5,
    BosFull(u16),
    Config9,
    ConfigFull,
    String0,
    String(u8),
    SetConfiguration(u8),
    /// SET_LINE_CODING (baud).
    LineCoding(u32),
    /// SET_CONTROL_LINE_STATE (wValue).
    LineState(u16),
}

/// A step of the host's script.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(super) enum Op {
    Reset,
    Wait(f64),
    Control(Tag),
    /// A class request asked for through the API (waits for the enumeration).
    User(Tag),
    /// The enumeration is complete.
    Configured,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum Stage {
    Setup,
    DataIn,
    DataOut,
    StatusIn,
    StatusOut,
}

/// The control transfer under way.
#[derive(Debug, Clone)]
pub(super) struct Control {
    pub(super) tag: Tag,
    setup: [u8; 8],
    out: Vec<u8>,
    sent: usize,
    got: Vec<u8>,
    pub(super) stage: Stage,
    pub(super) next: Next,
    pub(super) deadline: f64,
}

fn setup(bm: u8, req: u8, value: u16, index: u16, length: u16) -> [u8; 8] {
    let (v, i, l) = (value.to_le_bytes(), index.to_le_bytes(), length.to_le_bytes());
    [bm, req, v[0], v[1], i[0], i[1], l[0], l[1]]
}

pub(super) fn describe(tag: Tag) -> String {
    match tag {
        Tag::Device64 => "GET_DESCRIPTOR(device, 64)".into(),
        Tag::SetAddress(a) => format!("SET_ADDRESS({a})"),
        Tag::Device18 => "GET_DESCRIPTOR(device, 18)".into(),
        Tag::Bos5 => "GET_DESCRIPTOR(BOS, 5)".into(),
        Tag::BosFull(n) => format!("GET_DESCRIPTOR(BOS, {n})"),
        Tag::Config9 => "GET_DESCRIPTOR(configuration, 9)".into(),
        Tag::ConfigFull => "GET_DESCRIPTOR(configuration, wTotalLength)".into(),
        Tag::String0 => "GET_DESCRIPTOR(string 0)".into(),
        Tag::String(i) => format!("GET_DESCRIPTOR(string {i})"),
        Tag::SetConfiguration(c) => format!("SET_CONFIGURATION({c})"),
        Tag::LineCoding(b) => format!("SET_LINE_CODING({b} 8N1)"),
        Tag::LineState(v) => format!("SET_CONTROL_LINE_STATE(0x{v:X})"),
    }
}

impl Host {
    /// Queues SET_LINE_CODING(baud, 8N1) (sent once enumerated).
    pub fn set_line_coding(&mut self, baud: u32) {
        self.script.push_back(Op::User(Tag::LineCoding(baud)));
    }

    /// Queues SET_CONTROL_LINE_STATE with DTR (and RTS) set or cleared.
    pub fn set_dtr(&mut self, dtr: bool) {
        self.script.push_back(Op::User(Tag::LineState(if dtr { 3 } else { 0 })));
    }

    /// The control requests queued and not yet started, described.
    pub fn queued(&self) -> Vec<String> {
        self.script
            .iter()
            .filter_map(|op| match op {
                Op::Control(t) | Op::User(t) => Some(describe(*t)),
                _ => None,
            })
            .collect()
    }

    /// Starts the control transfer `tag` (its SETUP goes out once the gap after the last one
    /// has passed).
    pub(super) fn start_control(&mut self, tag: Tag) {
        let iface = self.cdc.map_or(0, |c| c.comm_interface as u16);
        let (s, out) = match tag {
            Tag::Device64 => (setup(0x80, 6, 0x0100, 0, 64), vec![]),
            Tag::SetAddress(a) => (setup(0x00, 5, a as u16, 0, 0), vec![]),
            Tag::Device18 => (setup(0x80, 6, 0x0100, 0, 18), vec![]),
            Tag::Bos5 => (setup(0x80, 6, 0x0F00, 0, 5), vec![]),
            Tag::BosFull(n) => (setup(0x80, 6, 0x0F00, 0, n), vec![]),
            Tag::Config9 => (setup(0x80, 6, 0x0200, 0, 9), vec![]),
            Tag::ConfigFull => {
                let total = self.configuration.as_ref().map_or(9, |c| c.raw.len() as u16);
                (setup(0x80, 6, 0x0200, 0, total), vec![])
            }
            Tag::String0 => (setup(0x80, 6, 0x0300, 0, 255), vec![]),
            Tag::String(i) => (setup(0x80, 6, 0x0300 | i as u16, self.langid.unwrap_or(0x0409), 255), vec![]),
            Tag::SetConfiguration(c) => (setup(0x00, 9, c as u16, 0, 0), vec![]),
            Tag::LineCoding(b) => {
                let mut d = b.to_le_bytes().to_vec();
                d.extend([0, 0, 8]);
                (setup(0x21, 0x20, 0, iface, 7), d)
            }
            Tag::LineState(v) => (setup(0x21, 0x22, v, iface, 0), vec![]),
        };
        let start = self.now.max(self.ctrl_not_before);
        self.ctrl = Some(Control {
            tag,
            setup: s,
            out,
            sent: 0,
            got: vec![],
            stage: Stage::Setup,
            next: Next::At(start),
            deadline: start + CONTROL_TIMEOUT_S,
        });
    }

    pub(super) fn control_step(&mut self, dev: &mut Usbd, phy: Phy) -> Result<(), String> {
        let Some(mut c) = self.ctrl.take() else { return Ok(()) };
        let now = self.now;
        let what = describe(c.tag);
        let mps = self.mps0;
        let nak = |c: &mut Control, dev: &Usbd| c.next = Next::AfterChange(dev.generation);
        match c.stage {
            Stage::Setup => match dev.setup(self.addr, c.setup, phy)? {
                Handshake::Ack => {
                    c.stage = if c.setup[0] & 0x80 != 0 {
                        Stage::DataIn
                    } else if c.setup[6] != 0 || c.setup[7] != 0 {
                        Stage::DataOut
                    } else {
                        Stage::StatusIn
                    };
                    c.next = Next::At(now + txn_s(8));
                }
                Handshake::Silent => {
                    self.silent(&format!("the SETUP of {what}"), dev, phy);
                    return Ok(());
                }
                h => {
                    self.control_done(c.tag, Err(format!("{what}: SETUP answered {h:?}")));
                    return Ok(());
                }
            },
            Stage::DataIn => match dev.in_token(self.addr, 0, phy)? {
                Ok(p) => {
                    if p.data.len() > mps {
                        self.control_done(c.tag, Err(format!("{what}: babble: a {}-byte packet on EP0 (max {mps})", p.data.len())));
                        return Ok(());
                    }
                    let want = u16::from_le_bytes([c.setup[6], c.setup[7]]) as usize;
                    let room = want - c.got.len().min(want);
                    c.got.extend_from_slice(&p.data[..p.data.len().min(room)]);
                    if p.data.len() < mps || c.got.len() >= want {
                        c.stage = Stage::StatusOut;
                    }
                    c.next = Next::At(now + txn_s(p.data.len()));
                }
                Err(Handshake::Nak) => nak(&mut c, dev),
                Err(Handshake::Stall) => {
                    self.control_done(c.tag, Err(format!("STALL on {what} (data stage)")));
                    return Ok(());
                }
                Err(_) => {
                    self.silent(&format!("the data stage of {what}"), dev, phy);
                    return Ok(());
                }
            },
            Stage::DataOut => {
                let end = (c.sent + mps).min(c.out.len());
                let chunk = c.out[c.sent..end].to_vec();
                match dev.out_token(self.addr, 0, &chunk, true, phy)? {
                    Handshake::Ack => {
                        c.sent = end;
                        if c.sent >= c.out.len() {
                            c.stage = Stage::StatusIn;
                        }
                        c.next = Next::At(now + txn_s(chunk.len()));
                    }
                    Handshake::Nak => nak(&mut c, dev),
                    Handshake::Stall => {
                        self.control_done(c.tag, Err(format!("STALL on {what} (data stage)")));
                        return Ok(());
                    }
                    Handshake::Silent => {
                        self.silent(&format!("the data stage of {what}"), dev, phy);
                        return Ok(());
                    }
                }
            }
            Stage::StatusIn => match dev.in_token(self.addr, 0, phy)? {
                Ok(p) if p.data.is_empty() => {
                    self.ctrl_not_before = now + txn_s(0) + CONTROL_GAP_S;
                    self.control_done(c.tag, Ok(vec![]));
                    return Ok(());
                }
                Ok(p) => {
                    self.control_done(c.tag, Err(format!("{what}: {} data bytes in the status stage", p.data.len())));
                    return Ok(());
                }
                Err(Handshake::Nak) => nak(&mut c, dev),
                Err(Handshake::Stall) => {
                    self.control_done(c.tag, Err(format!("STALL on {what} (status stage)")));
                    return Ok(());
                }
                Err(_) => {
                    self.silent(&format!("the status stage of {what}"), dev, phy);
                    return Ok(());
                }
            },
            Stage::StatusOut => match dev.out_token(self.addr, 0, &[], true, phy)? {
                Handshake::Ack => {
                    self.ctrl_not_before = now + txn_s(0) + CONTROL_GAP_S;
                    let got = std::mem::take(&mut c.got);
                    self.control_done(c.tag, Ok(got));
                    return Ok(());
                }
                Handshake::Nak => nak(&mut c, dev),
                Handshake::Stall => {
                    self.control_done(c.tag, Err(format!("STALL on {what} (status stage)")));
                    return Ok(());
                }
                Handshake::Silent => {
                    self.silent(&format!("the status stage of {what}"), dev, phy);
                    return Ok(());
                }
            },
        }
        self.ctrl = Some(c);
        Ok(())
    }

    /// A control transfer ended: the enumeration's next step.
    pub(super) fn control_done(&mut self, tag: Tag, r: Result<Vec<u8>, String>) {
        let d = match r {
            Ok(d) => {
                self.note(format!("{} ok ({} bytes)", describe(tag), d.len()));
                d
            }
            Err(e) if matches!(tag, Tag::Bos5 | Tag::BosFull(_)) && e.starts_with("STALL") => {
                // Linux goes on without the BOS descriptor.
                self.note(format!("{e}: ignored"));
                self.script.push_front(Op::Control(Tag::Config9));
                return;
            }
            Err(e) => {
                self.fail(e);
                return;
            }
        };
        let front = |h: &mut Host, ops: &[Op]| {
            for op in ops.iter().rev() {
                h.script.push_front(*op);
            }
        };
        let r: Result<(), String> = (|| {
            match tag {
                Tag::Device64 => {
                    self.mps0 = parse_device_prefix(&d)? as usize;
                    let a = self.next_devnum;
                    self.next_devnum = if a >= 127 { 1 } else { a + 1 };
                    front(self, &[Op::Reset, Op::Wait(RECOVERY_S), Op::Control(Tag::SetAddress(a))]);
                }
                Tag::SetAddress(a) => {
                    self.addr = a;
                    front(self, &[Op::Wait(SET_ADDRESS_WAIT_S), Op::Control(Tag::Device18)]);
                }
                Tag::Device18 => {
                    let dd = parse_device(&d)?;
                    self.mps0 = dd.max_packet0 as usize;
                    let bos = dd.usb >= 0x0201;
                    self.device = Some(dd);
                    front(self, &[Op::Control(if bos { Tag::Bos5 } else { Tag::Config9 })]);
                }
                Tag::Bos5 => {
                    let total = parse_bos_header(&d)?;
                    front(self, &[Op::Control(if total > 5 { Tag::BosFull(total) } else { Tag::Config9 })]);
                }
                Tag::BosFull(n) => {
                    check_bos(&d, n)?;
                    self.bos = Some(d.clone());
                    front(self, &[Op::Control(Tag::Config9)]);
                }
                Tag::Config9 => {
                    self.configuration = Some(parse_configuration_header(&d)?);
                    front(self, &[Op::Control(Tag::ConfigFull)]);
                }
                Tag::ConfigFull => {
                    let c = parse_configuration(&d)?;
                    self.cdc = Some(find_cdc(&c)?);
                    self.configuration = Some(c);
                    front(self, &[Op::Control(Tag::String0)]);
                }
                Tag::String0 => {
                    self.langid = Some(parse_langid(&d)?);
                    let (m, p, s) = self.device.as_ref().map_or((0, 0, 0), |dd| dd.strings);
                    let mut ops = vec![];
                    for i in [p, m, s] {
                        if i != 0 && !ops.contains(&Op::Control(Tag::String(i))) {
                            ops.push(Op::Control(Tag::String(i)));
                        }
                    }
                    let cfg = self.configuration.as_ref().map_or(1, |c| c.value);
                    ops.extend([
                        Op::Control(Tag::SetConfiguration(cfg)),
                        Op::Control(Tag::LineCoding(115_200)),
                        Op::Control(Tag::LineState(3)),
                        Op::Configured,
                    ]);
                    front(self, &ops);
                }
                Tag::String(i) => {
                    let s = parse_string(&d).map_err(|e| format!("string {i}: {e}"))?;
                    self.strings.retain(|x| x.0 != i);
                    self.strings.push((i, s));
                }
                Tag::SetConfiguration(_) => {
                    self.in_toggle = false;
                    self.out_toggle = false;
                }
                Tag::LineCoding(b) => self.line.0 = b,
                Tag::LineState(v) => self.line.1 = v,
            }
            Ok(())
        })();
        if let Err(e) = r {
            self.fail(e);
        }
    }
}
