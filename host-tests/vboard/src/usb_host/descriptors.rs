//! Descriptors: the types the host keeps of what the device described (device, configuration
//! with its interfaces and endpoints, the CDC-ACM function) and the parsers that validate the
//! bytes of each GET_DESCRIPTOR reply (a malformed one fails the enumeration).
/// The standard device descriptor.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct DeviceDescriptor {
    /// bcdUSB.
    pub usb: u16,
    /// bDeviceClass, bDeviceSubClass, bDeviceProtocol.
    pub class: (u8, u8, u8),
    /// bMaxPacketSize0.
    pub max_packet0: u8,
    /// idVendor.
    pub vid: u16,
    /// idProduct.
    pub pid: u16,
    /// bcdDevice.
    pub device: u16,
    /// iManufacturer, iProduct, iSerialNumber.
    pub strings: (u8, u8, u8),
    /// bNumConfigurations.
    pub num_configurations: u8,
}

/// An endpoint descriptor.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Endpoint {
    /// bEndpointAddress (bit 7: IN).
    pub address: u8,
    /// bmAttributes (bits 1:0: 0 control, 1 iso, 2 bulk, 3 interrupt).
    pub attributes: u8,
    /// wMaxPacketSize.
    pub max_packet: u16,
    /// bInterval.
    pub interval: u8,
}

/// An interface descriptor with its endpoints.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Interface {
    /// bInterfaceNumber.
    pub number: u8,
    /// bInterfaceClass, bInterfaceSubClass, bInterfaceProtocol.
    pub class: (u8, u8, u8),
    /// Its endpoints.
    pub endpoints: Vec<Endpoint>,
}

/// The configuration descriptor as parsed.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Configuration {
    /// The raw bytes (wTotalLength).
    pub raw: Vec<u8>,
    /// bConfigurationValue.
    pub value: u8,
    /// bmAttributes.
    pub attributes: u8,
    /// bMaxPower (2 mA units).
    pub max_power: u8,
    /// The interfaces in order.
    pub interfaces: Vec<Interface>,
}

/// The CDC-ACM function found in the configuration.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Cdc {
    /// The communication interface (class requests go there).
    pub comm_interface: u8,
    /// Its notification endpoint (interrupt IN), if any.
    pub notify_in: Option<u8>,
    /// The data interface.
    pub data_interface: u8,
    /// Bulk IN endpoint address and max packet.
    pub bulk_in: (u8, u16),
    /// Bulk OUT endpoint address and max packet.
    pub bulk_out: (u8, u16),
}

/// Parses a device descriptor.
pub fn parse_device(d: &[u8]) -> Result<DeviceDescriptor, String> {
    if d.len() != 18 || d[0] != 18 || d[1] != 1 {
        return Err(format!(
            "malformed device descriptor: {} bytes, bLength {}, bDescriptorType {}",
            d.len(),
            d.first().copied().unwrap_or(0),
            d.get(1).copied().unwrap_or(0)
        ));
    }
    let u = |i: usize| u16::from_le_bytes([d[i], d[i + 1]]);
    Ok(DeviceDescriptor {
        usb: u(2),
        class: (d[4], d[5], d[6]),
        max_packet0: max_packet0(d[7])?,
        vid: u(8),
        pid: u(10),
        device: u(12),
        strings: (d[14], d[15], d[16]),
        num_configurations: d[17],
    })
}

/// bMaxPacketSize0, if a full-speed value (8, 16, 32 or 64).
fn max_packet0(v: u8) -> Result<u8, String> {
    if ![8, 16, 32, 64].contains(&v) {
        return Err(format!("malformed device descriptor: bMaxPacketSize0 {v}"));
    }
    Ok(v)
}

/// The first 8 bytes (at least) of the device descriptor, the reply to the first
/// GET_DESCRIPTOR(device, 64) at address 0: bMaxPacketSize0.
pub(super) fn parse_device_prefix(d: &[u8]) -> Result<u8, String> {
    if d.len() < 8 || d[1] != 1 {
        return Err(format!("malformed device descriptor: {} bytes to GET_DESCRIPTOR(device, 64)", d.len()));
    }
    max_packet0(d[7])
}

/// The BOS descriptor header (GET_DESCRIPTOR(BOS, 5)): wTotalLength.
pub(super) fn parse_bos_header(d: &[u8]) -> Result<u16, String> {
    if d.len() != 5 || d[0] != 5 || d[1] != 0x0F {
        return Err(format!("malformed BOS descriptor: {} bytes to GET_DESCRIPTOR(BOS, 5)", d.len()));
    }
    Ok(u16::from_le_bytes([d[2], d[3]]))
}

/// Checks the full BOS descriptor (wTotalLength `total`): device capabilities filling it exactly.
pub(super) fn check_bos(d: &[u8], total: u16) -> Result<(), String> {
    if d.len() != total as usize {
        return Err(format!("malformed BOS descriptor: wTotalLength {total}, {} bytes received", d.len()));
    }
    let mut i = 5;
    while i < d.len() {
        let len = d[i] as usize;
        if len < 3 || i + len > d.len() || d[i + 1] != 0x10 {
            return Err(format!("malformed BOS descriptor: a capability of bLength {len} at byte {i}"));
        }
        i += len;
    }
    Ok(())
}

/// The configuration descriptor header (GET_DESCRIPTOR(configuration, 9)): a [`Configuration`]
/// without interfaces whose `raw` is wTotalLength zero bytes (the length to ask for next).
pub(super) fn parse_configuration_header(d: &[u8]) -> Result<Configuration, String> {
    if d.len() != 9 || d[0] != 9 || d[1] != 2 {
        return Err(format!("malformed configuration descriptor: {} bytes to GET_DESCRIPTOR(configuration, 9)", d.len()));
    }
    let total = u16::from_le_bytes([d[2], d[3]]);
    if total < 9 {
        return Err(format!("malformed configuration descriptor: wTotalLength {total}"));
    }
    Ok(Configuration { raw: vec![0; total as usize], value: d[5], attributes: d[7], max_power: d[8], interfaces: vec![] })
}

/// Parses a full configuration descriptor (with its interfaces and endpoints).
pub fn parse_configuration(d: &[u8]) -> Result<Configuration, String> {
    if d.len() < 9 || d[0] != 9 || d[1] != 2 {
        return Err("malformed configuration descriptor header".into());
    }
    let total = u16::from_le_bytes([d[2], d[3]]) as usize;
    if total != d.len() {
        return Err(format!("malformed configuration descriptor: wTotalLength {total}, {} bytes received", d.len()));
    }
    let mut interfaces: Vec<Interface> = vec![];
    let mut i = 9;
    while i < d.len() {
        let (len, ty) = (d[i] as usize, d.get(i + 1).copied().unwrap_or(0));
        if len < 2 || i + len > d.len() {
            return Err(format!(
                "malformed configuration descriptor: a descriptor of bLength {len} at byte {i} overruns wTotalLength {total}"
            ));
        }
        let s = &d[i..i + len];
        match ty {
            4 => {
                if len < 9 {
                    return Err(format!("malformed interface descriptor at byte {i} (bLength {len})"));
                }
                interfaces.push(Interface { number: s[2], class: (s[5], s[6], s[7]), endpoints: vec![] });
            }
            5 => {
                if len < 7 {
                    return Err(format!("malformed endpoint descriptor at byte {i} (bLength {len})"));
                }
                let ep = Endpoint { address: s[2], attributes: s[3], max_packet: u16::from_le_bytes([s[4], s[5]]), interval: s[6] };
                if ep.max_packet == 0 || ep.max_packet > 64 {
                    return Err(format!("endpoint 0x{:02X}: wMaxPacketSize {} is not a full-speed value", ep.address, ep.max_packet));
                }
                match interfaces.last_mut() {
                    Some(itf) => itf.endpoints.push(ep),
                    None => return Err(format!("endpoint descriptor at byte {i} before any interface")),
                }
            }
            _ => {}
        }
        i += len;
    }
    Ok(Configuration { raw: d.to_vec(), value: d[5], attributes: d[7], max_power: d[8], interfaces })
}

/// The CDC-ACM function of a configuration: the communication interface (class 2, subclass 2)
/// and the data interface (class 10) with one bulk IN and one bulk OUT endpoint.
pub fn find_cdc(c: &Configuration) -> Result<Cdc, String> {
    let comm =
        c.interfaces.iter().find(|i| i.class.0 == 2 && i.class.1 == 2).ok_or("no CDC-ACM communication interface (class 2, subclass 2)")?;
    let data = c.interfaces.iter().find(|i| i.class.0 == 10).ok_or("no CDC data interface (class 10)")?;
    let bulk = |dir_in: bool| {
        data.endpoints.iter().find(|e| e.attributes & 3 == 2 && (e.address & 0x80 != 0) == dir_in).map(|e| (e.address, e.max_packet))
    };
    let notify_in = comm.endpoints.iter().find(|e| e.attributes & 3 == 3 && e.address & 0x80 != 0).map(|e| e.address);
    Ok(Cdc {
        comm_interface: comm.number,
        notify_in,
        data_interface: data.number,
        bulk_in: bulk(true).ok_or("the CDC data interface has no bulk IN endpoint")?,
        bulk_out: bulk(false).ok_or("the CDC data interface has no bulk OUT endpoint")?,
    })
}

/// Parses a string descriptor (UTF-16LE).
pub fn parse_string(d: &[u8]) -> Result<String, String> {
    if d.len() < 2 || d[0] as usize != d.len() || d[1] != 3 || !d.len().is_multiple_of(2) {
        return Err(format!("malformed string descriptor: {} bytes, bLength {}", d.len(), d.first().copied().unwrap_or(0)));
    }
    let units: Vec<u16> = d[2..].chunks_exact(2).map(|c| u16::from_le_bytes([c[0], c[1]])).collect();
    String::from_utf16(&units).map_err(|e| format!("malformed string descriptor: {e}"))
}

/// String descriptor 0: the first language id.
pub(super) fn parse_langid(d: &[u8]) -> Result<u16, String> {
    if d.len() < 4 || d[1] != 3 || d[0] as usize != d.len() {
        return Err(format!("malformed string descriptor 0 ({} bytes)", d.len()));
    }
    Ok(u16::from_le_bytes([d[2], d[3]]))
}
