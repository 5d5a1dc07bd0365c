//! EGL's lookup of functions by name: the renderer finds EGL extensions
//! through it, and the view culling the OpenGL 1.x calls of its grid display
//! lists. Its own module so that both use it without depending on each other.

use std::ffi::{c_char, c_void};

#[link(name = "EGL")]
extern "C" {
    pub(super) fn eglGetProcAddress(name: *const c_char) -> *mut c_void;
}
