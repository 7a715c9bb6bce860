//! End-to-end tests of `meshsmooth serve`: each test starts the real
//! binary on a loopback port and talks HTTP/1.1 to it.

mod contract;
mod errors;
mod jobs;
mod operations;
mod overload;
mod parity;
mod shared;
mod support;
mod weld;
