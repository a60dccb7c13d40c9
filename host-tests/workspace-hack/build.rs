//! Empty: it lets the crate's build-dependencies unify the proc-macros' features.
fn main() {}
