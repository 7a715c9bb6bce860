//! Fuzzes the OFF reader and writer: no panic, a faithful round trip and
//! bounded heap use (see `common.rs`).
#![no_main]

mod common;

use libfuzzer_sys::fuzz_target;
use meshsmooth_core::io::Format;

#[global_allocator]
static ALLOCATOR: common::Counting = common::Counting;

fuzz_target!(|data: &[u8]| common::round_trip(data, Format::Off));
