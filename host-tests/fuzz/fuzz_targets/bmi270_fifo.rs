#![no_main]
libfuzzer_sys::fuzz_target!(|data: &[u8]| gyrocal_fuzz::bmi270_fifo(data));
