//! End-to-end tests of the web page at `/` in a real headless Chromium
//! (Debian's `chromium`, driven over the DevTools protocol on a pipe), and
//! of the sample meshes the page and the README use.

#[path = "../service/support.rs"]
mod support;

mod cdp;
mod page;
mod samples;
