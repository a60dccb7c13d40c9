#![no_main]
libfuzzer_sys::fuzz_target!(|data: &[u8]| gyrocal_fuzz::lsm9ds1_fifo(data));
