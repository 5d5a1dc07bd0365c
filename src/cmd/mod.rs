pub mod bench;
pub mod contexts;
pub mod replay;
pub mod serve;
pub mod submit;
pub mod tables;
pub mod token;
