pub mod bench;
pub mod contexts;
pub mod replay;
