//! Headless offscreen rendering with MuJoCo 2.2's OpenGL renderer on an EGL
//! context from Mesa (surfaceless platform, PBUFFER config), docs/original-d3il.md §01.6.
//!
//! A [`Renderer`] owns one EGL context and one `mjrContext`; it is bound to the
//! thread that created it (OpenGL contexts are current per thread), so it is
//! neither `Send` nor `Sync`. The evaluator keeps one per worker thread and all
//! rollouts on that thread share it.

use super::egl::eglGetProcAddress;
use super::view::{cull_outside_frustum, cull_under_slabs, Frustum, PlaneLists};
use super::{ffi, guarded, install_handlers, Data, MjError, Model};
use std::ffi::{c_char, c_void, CStr};
use std::marker::PhantomData;
use std::sync::Arc;

type EglDisplay = *mut c_void;
type EglConfig = *mut c_void;
type EglSurface = *mut c_void;
type EglContext = *mut c_void;
type EglBoolean = u32;
type EglInt = i32;

#[link(name = "EGL")]
extern "C" {
    fn eglGetDisplay(native: *mut c_void) -> EglDisplay;
    fn eglInitialize(dpy: EglDisplay, major: *mut EglInt, minor: *mut EglInt) -> EglBoolean;
    fn eglTerminate(dpy: EglDisplay) -> EglBoolean;
    fn eglQueryString(dpy: EglDisplay, name: EglInt) -> *const c_char;
    fn eglChooseConfig(
        dpy: EglDisplay,
        attrib: *const EglInt,
        configs: *mut EglConfig,
        size: EglInt,
        num: *mut EglInt,
    ) -> EglBoolean;
    fn eglCreatePbufferSurface(
        dpy: EglDisplay,
        config: EglConfig,
        attrib: *const EglInt,
    ) -> EglSurface;
    fn eglBindAPI(api: u32) -> EglBoolean;
    fn eglCreateContext(
        dpy: EglDisplay,
        config: EglConfig,
        share: EglContext,
        attrib: *const EglInt,
    ) -> EglContext;
    fn eglMakeCurrent(
        dpy: EglDisplay,
        draw: EglSurface,
        read: EglSurface,
        ctx: EglContext,
    ) -> EglBoolean;
    fn eglDestroyContext(dpy: EglDisplay, ctx: EglContext) -> EglBoolean;
    fn eglDestroySurface(dpy: EglDisplay, surface: EglSurface) -> EglBoolean;
    fn eglGetError() -> EglInt;
}

const EGL_NONE: EglInt = 0x3038;
const EGL_SURFACE_TYPE: EglInt = 0x3033;
const EGL_PBUFFER_BIT: EglInt = 0x0001;
const EGL_RENDERABLE_TYPE: EglInt = 0x3040;
const EGL_OPENGL_BIT: EglInt = 0x0008;
const EGL_RED_SIZE: EglInt = 0x3024;
const EGL_GREEN_SIZE: EglInt = 0x3023;
const EGL_BLUE_SIZE: EglInt = 0x3022;
const EGL_DEPTH_SIZE: EglInt = 0x3025;
const EGL_WIDTH: EglInt = 0x3057;
const EGL_HEIGHT: EglInt = 0x3056;
const EGL_OPENGL_API: u32 = 0x30A2;
const EGL_EXTENSIONS: EglInt = 0x3055;
const EGL_VENDOR: EglInt = 0x3053;
const EGL_PLATFORM_SURFACELESS_MESA: u32 = 0x31DD;
const EGL_PLATFORM_DEVICE_EXT: u32 = 0x313F;

type QueryDevicesExt =
    unsafe extern "C" fn(max: EglInt, devices: *mut *mut c_void, num: *mut EglInt) -> EglBoolean;
type QueryDeviceStringExt =
    unsafe extern "C" fn(device: *mut c_void, name: EglInt) -> *const c_char;

/// Mesa's software (llvmpipe) EGL device, if the EGL device extensions are
/// there. Rendering on it gives the same pixels on every host, GPU or not.
///
/// # Safety
/// EGL must be loaded (it is linked).
unsafe fn software_device(client: &str) -> Option<*mut c_void> {
    if !client.contains("EGL_EXT_device_enumeration") && !client.contains("EGL_EXT_device_base") {
        return None;
    }
    let q = eglGetProcAddress(c"eglQueryDevicesEXT".as_ptr());
    let qs = eglGetProcAddress(c"eglQueryDeviceStringEXT".as_ptr());
    if q.is_null() || qs.is_null() {
        return None;
    }
    let q: QueryDevicesExt = std::mem::transmute(q);
    let qs: QueryDeviceStringExt = std::mem::transmute(qs);
    let mut devices = [std::ptr::null_mut(); 16];
    let mut n = 0;
    if q(devices.len() as EglInt, devices.as_mut_ptr(), &mut n) == 0 {
        return None;
    }
    devices[..n.clamp(0, 16) as usize]
        .iter()
        .copied()
        .find(|&d| {
            let ext = qs(d, EGL_EXTENSIONS);
            !ext.is_null()
                && CStr::from_ptr(ext)
                    .to_string_lossy()
                    .contains("EGL_MESA_device_software")
        })
}

type GetPlatformDisplayExt =
    unsafe extern "C" fn(platform: u32, native: *mut c_void, attrib: *const EglInt) -> EglDisplay;

fn egl_error(what: &str) -> MjError {
    MjError::Render(egl_message(what))
}

fn egl_message(what: &str) -> String {
    // SAFETY: plain query of the thread's last EGL error.
    let code = unsafe { eglGetError() };
    format!(
        "{what} failed (EGL error 0x{code:04x}); headless rendering needs Mesa's EGL: \
         apt-get install -y libegl1 libegl-mesa0 libgl1-mesa-dri libgbm1"
    )
}

/// The process-wide EGL display (Mesa's software device, else the
/// surfaceless platform), and the software device when EGL lists it.
struct Display(EglDisplay, &'static str, Option<EglDevice>);
// SAFETY: EGLDisplay and EGLDeviceEXT handles are process-global and
// thread-safe by the EGL spec.
unsafe impl Send for Display {}
unsafe impl Sync for Display {}

type EglDevice = *mut c_void;
type EglAttrib = isize;
const EGL_DEVICE_EXT: EglAttrib = 0x322C;
type GetPlatformDisplay = unsafe extern "C" fn(
    platform: u32,
    native: *mut c_void,
    attrib: *const EglAttrib,
) -> EglDisplay;

static DISPLAY: std::sync::OnceLock<Result<Display, String>> = std::sync::OnceLock::new();

/// The EGL displays renderers use: Mesa gives each display its own llvmpipe
/// screen, and a screen rasterizes one context's frame at a time (its
/// rasterizer sits behind one mutex), so renderers on different worker
/// threads that shared a display would take turns (measured in
/// docs/images.md). `displays[slot]`: the display and how many renderers
/// use it; `next`: the [`other_display`] candidate to try when all are in
/// use (candidates that are not the software device are skipped for good).
struct Pool {
    displays: Vec<(EglDisplay, usize)>,
    next: usize,
}
// SAFETY: as for Display.
unsafe impl Send for Pool {}

static POOL: std::sync::Mutex<Pool> = std::sync::Mutex::new(Pool {
    displays: Vec::new(),
    next: 1,
});

/// A renderer's display: a free one of the pool, a new one when Mesa can
/// make another, else the least used.
struct Lease {
    dpy: EglDisplay,
    slot: usize,
}

impl Lease {
    fn acquire() -> Result<Lease, MjError> {
        let base = display_and_platform()?;
        let mut pool = POOL.lock().unwrap_or_else(|e| e.into_inner());
        if pool.displays.is_empty() {
            pool.displays.push((base.0, 0));
        }
        let free = pool.displays.iter().position(|&(_, users)| users == 0);
        let slot = match free {
            Some(k) => k,
            None => {
                let mut made = None;
                while made.is_none() && pool.next <= LAST_OTHER_DISPLAY {
                    let k = pool.next;
                    pool.next += 1;
                    // SAFETY: EGL calls with valid, EGL_NONE-terminated attribute lists.
                    made = base.2.and_then(|dev| unsafe { other_display(dev, k) });
                }
                match made {
                    Some(dpy) => {
                        pool.displays.push((dpy, 0));
                        pool.displays.len() - 1
                    }
                    None => (0..pool.displays.len())
                        .min_by_key(|&i| pool.displays[i].1)
                        .unwrap_or(0),
                }
            }
        };
        pool.displays[slot].1 += 1;
        Ok(Lease {
            dpy: pool.displays[slot].0,
            slot,
        })
    }
}

impl Drop for Lease {
    fn drop(&mut self) {
        let mut pool = POOL.lock().unwrap_or_else(|e| e.into_inner());
        pool.displays[self.slot].1 -= 1;
    }
}

/// Display `k` (k ≥ 1) of the pool, on Mesa's software device like the
/// first. EGL 1.5 returns the same display for the same parameters only, and
/// Mesa counts a missing attribute list and an empty one as different
/// parameters (its `_eglFindDisplay`), so k = 1 is the device platform with
/// an empty list and k = 2, 3 the surfaceless platform without and with one,
/// each kept only if its device is the software one. Mesa accepts no other
/// display attributes on these platforms, so there are at most four. A
/// display that is not the software device is terminated again.
///
/// # Safety
/// EGL must be loaded (it is linked).
unsafe fn other_display(dev: EglDevice, k: usize) -> Option<EglDisplay> {
    let f = eglGetProcAddress(c"eglGetPlatformDisplay".as_ptr());
    if f.is_null() {
        return None;
    }
    let f: GetPlatformDisplay = std::mem::transmute(f);
    let empty = [EGL_NONE as EglAttrib];
    let dpy = match k {
        1 => f(EGL_PLATFORM_DEVICE_EXT, dev, empty.as_ptr()),
        2 => f(
            EGL_PLATFORM_SURFACELESS_MESA,
            std::ptr::null_mut(),
            std::ptr::null(),
        ),
        3 => f(
            EGL_PLATFORM_SURFACELESS_MESA,
            std::ptr::null_mut(),
            empty.as_ptr(),
        ),
        _ => return None,
    };
    debug_assert!(k <= LAST_OTHER_DISPLAY);
    let (mut major, mut minor) = (0, 0);
    if dpy.is_null() || eglInitialize(dpy, &mut major, &mut minor) == 0 {
        return None;
    }
    if k == 1 || is_software(dpy) {
        Some(dpy)
    } else {
        eglTerminate(dpy);
        None
    }
}

/// The last candidate [`other_display`] knows.
const LAST_OTHER_DISPLAY: usize = 3;

type QueryDisplayAttribExt =
    unsafe extern "C" fn(dpy: EglDisplay, attribute: EglInt, value: *mut EglAttrib) -> EglBoolean;

/// Whether an initialised display runs on Mesa's software device.
///
/// # Safety
/// `dpy` must be an initialised display.
unsafe fn is_software(dpy: EglDisplay) -> bool {
    let q = eglGetProcAddress(c"eglQueryDisplayAttribEXT".as_ptr());
    let qs = eglGetProcAddress(c"eglQueryDeviceStringEXT".as_ptr());
    if q.is_null() || qs.is_null() {
        return false;
    }
    let q: QueryDisplayAttribExt = std::mem::transmute(q);
    let qs: QueryDeviceStringExt = std::mem::transmute(qs);
    let mut dev: EglAttrib = 0;
    if q(dpy, EGL_DEVICE_EXT as EglInt, &mut dev) == 0 || dev == 0 {
        return false;
    }
    let ext = qs(dev as *mut c_void, EGL_EXTENSIONS);
    !ext.is_null()
        && CStr::from_ptr(ext)
            .to_string_lossy()
            .contains("EGL_MESA_device_software")
}

/// Mesa llvmpipe's rasterizer thread count, set before the driver loads
/// unless the user set it: 0 = rasterize on the calling thread. A 96×96
/// frame is too small to split into tiles worth the hand-off, and the
/// evaluator already renders on every core (one context per worker thread),
/// so llvmpipe's own pool (one thread per core, per context) only competes
/// with the workers for the same cores (measurements in docs/images.md).
pub const LP_NUM_THREADS: &str = "0";

/// Sets [`LP_NUM_THREADS`] in the process environment unless the user set
/// it. Mesa reads it when `eglInitialize` creates an llvmpipe screen.
/// Changing the environment while other threads may read it is a data race
/// in libc, so a program calls this first thing in `main`, before it starts
/// any thread; the first renderer calls it again (a no-op then) for
/// programs that did not, such as test harnesses.
pub fn set_llvmpipe_defaults() {
    if std::env::var_os("LP_NUM_THREADS").is_none() {
        std::env::set_var("LP_NUM_THREADS", LP_NUM_THREADS);
    }
}

fn display_and_platform() -> Result<&'static Display, MjError> {
    let d = DISPLAY.get_or_init(|| {
        set_llvmpipe_defaults();
        // SAFETY: EGL entry points with valid arguments; the returned pointers
        // are checked before use.
        unsafe {
            let client = eglQueryString(std::ptr::null_mut(), EGL_EXTENSIONS);
            let client = if client.is_null() {
                String::new()
            } else {
                CStr::from_ptr(client).to_string_lossy().into_owned()
            };
            let mut dpy: EglDisplay = std::ptr::null_mut();
            let mut platform = "default display";
            let device = software_device(&client);
            let f = eglGetProcAddress(c"eglGetPlatformDisplayEXT".as_ptr());
            if !f.is_null() {
                let f: GetPlatformDisplayExt = std::mem::transmute(f);
                // Prefer Mesa's software device (deterministic pixels on any
                // host), else the surfaceless platform.
                if let Some(dev) = device {
                    dpy = f(EGL_PLATFORM_DEVICE_EXT, dev, std::ptr::null());
                    platform = "software device";
                }
                if dpy.is_null() && client.contains("EGL_MESA_platform_surfaceless") {
                    dpy = f(
                        EGL_PLATFORM_SURFACELESS_MESA,
                        std::ptr::null_mut(),
                        std::ptr::null(),
                    );
                    platform = "surfaceless platform";
                }
            }
            if dpy.is_null() {
                dpy = eglGetDisplay(std::ptr::null_mut());
            }
            if dpy.is_null() {
                return Err(egl_message("eglGetPlatformDisplayEXT"));
            }
            let (mut major, mut minor) = (0, 0);
            if eglInitialize(dpy, &mut major, &mut minor) == 0 {
                return Err(egl_message("eglInitialize"));
            }
            Ok(Display(dpy, platform, device))
        }
    });
    match d {
        Ok(d) => Ok(d),
        Err(e) => Err(MjError::Render(e.clone())),
    }
}

/// EGL vendor and platform (e.g. "Mesa Project, software device"), for logs
/// and `d3il bench render`.
pub fn egl_vendor() -> Result<String, MjError> {
    let &Display(dpy, platform, _) = display_and_platform()?;
    // SAFETY: initialised display; the string is static.
    let v = unsafe { eglQueryString(dpy, EGL_VENDOR) };
    let vendor = if v.is_null() {
        "unknown vendor".into()
    } else {
        // SAFETY: non-null, NUL-terminated static string.
        unsafe { CStr::from_ptr(v) }.to_string_lossy().into_owned()
    };
    Ok(format!("{vendor}, {platform}"))
}

/// One offscreen renderer: EGL context + MuJoCo render context + scene.
pub struct Renderer {
    model: Arc<Model>,
    /// Private copy of the model whose offscreen buffer is exactly the frame
    /// size (the shared model is read-only). Rendering reads only visual
    /// fields, identical in both; a smaller buffer gives the same pixels in
    /// the bottom-left viewport and makes multisample resolves much cheaper.
    own: std::ptr::NonNull<ffi::mjModel>,
    /// This renderer's display (given back after the context is gone).
    lease: Lease,
    surface: EglSurface,
    ctx: EglContext,
    con: Box<ffi::mjrContext>,
    scn: Box<ffi::mjvScene>,
    opt: Box<ffi::mjvOption>,
    cam: Box<ffi::mjvCamera>,
    pert: Box<ffi::mjvPerturb>,
    /// Per camera, the ground plane's grid cut to the cells in view.
    planes: Option<PlaneLists>,
    /// Geoms of the last frame left out as hidden under the table top.
    hidden: usize,
    /// Draw those too (tests compare the frames both ways).
    keep_hidden: bool,
    width: usize,
    height: usize,
    // The GL context is current on the creating thread only.
    _not_send: PhantomData<*mut ()>,
}

impl Renderer {
    /// Creates an EGL context on this thread and MuJoCo's render context for
    /// `model`, for frames of `width` × `height` pixels.
    pub fn new(model: Arc<Model>, width: usize, height: usize) -> Result<Renderer, MjError> {
        Self::with_samples(model, width, height, None)
    }

    /// [`Renderer::new`] with `samples` multisamples per pixel instead of the
    /// model's `offsamples` (videos: pictures for people, not for policies).
    pub fn with_samples(
        model: Arc<Model>,
        width: usize,
        height: usize,
        samples: Option<usize>,
    ) -> Result<Renderer, MjError> {
        install_handlers();
        let lease = Lease::acquire()?;
        let dpy = lease.dpy;
        // SAFETY: valid display; attribute lists are EGL_NONE-terminated; every
        // returned handle is checked; the MuJoCo structs are boxed (stable
        // addresses) and initialised with their default functions before use.
        unsafe {
            let attrs = [
                EGL_SURFACE_TYPE,
                EGL_PBUFFER_BIT,
                EGL_RENDERABLE_TYPE,
                EGL_OPENGL_BIT,
                EGL_RED_SIZE,
                8,
                EGL_GREEN_SIZE,
                8,
                EGL_BLUE_SIZE,
                8,
                EGL_DEPTH_SIZE,
                24,
                EGL_NONE,
            ];
            let mut config: EglConfig = std::ptr::null_mut();
            let mut n = 0;
            if eglChooseConfig(dpy, attrs.as_ptr(), &mut config, 1, &mut n) == 0 || n < 1 {
                return Err(egl_error(
                    "eglChooseConfig (PBUFFER, OpenGL, RGB8, depth 24)",
                ));
            }
            let pb = [
                EGL_WIDTH,
                width as EglInt,
                EGL_HEIGHT,
                height as EglInt,
                EGL_NONE,
            ];
            let surface = eglCreatePbufferSurface(dpy, config, pb.as_ptr());
            if surface.is_null() {
                return Err(egl_error("eglCreatePbufferSurface"));
            }
            if eglBindAPI(EGL_OPENGL_API) == 0 {
                eglDestroySurface(dpy, surface);
                return Err(egl_error("eglBindAPI(OpenGL)"));
            }
            let none = [EGL_NONE];
            let ctx = eglCreateContext(dpy, config, std::ptr::null_mut(), none.as_ptr());
            if ctx.is_null() {
                eglDestroySurface(dpy, surface);
                return Err(egl_error("eglCreateContext"));
            }
            if eglMakeCurrent(dpy, surface, surface, ctx) == 0 {
                eglDestroyContext(dpy, ctx);
                eglDestroySurface(dpy, surface);
                return Err(egl_error("eglMakeCurrent"));
            }
            let own =
                std::ptr::NonNull::new(ffi::mj_copyModel(std::ptr::null_mut(), model.ptr.as_ptr()))
                    .ok_or_else(|| {
                        eglMakeCurrent(
                            dpy,
                            std::ptr::null_mut(),
                            std::ptr::null_mut(),
                            std::ptr::null_mut(),
                        );
                        eglDestroyContext(dpy, ctx);
                        eglDestroySurface(dpy, surface);
                        MjError::Render("mj_copyModel could not allocate".into())
                    })?;
            (*own.as_ptr()).vis.global.offwidth = width as i32;
            (*own.as_ptr()).vis.global.offheight = height as i32;
            if let Some(n) = samples {
                (*own.as_ptr()).vis.quality.offsamples = n as i32;
            }
            // Shadows are off (below), so the 8192² shadow map of docs/original-d3il.md §01.1.2
            // (visual/quality shadowsize) would only hold ~256 MiB of memory per
            // GL context; same pixels without it (deviation noted in docs/images.md).
            (*own.as_ptr()).vis.quality.shadowsize = 0;
            let mut r = Renderer {
                model,
                own,
                lease,
                surface,
                ctx,
                con: Box::default(),
                scn: Box::default(),
                opt: Box::default(),
                cam: Box::default(),
                pert: Box::default(),
                planes: None,
                width,
                height,
                hidden: 0,
                keep_hidden: false,
                _not_send: PhantomData,
            };
            ffi::mjv_defaultOption(&mut *r.opt);
            ffi::mjv_defaultCamera(&mut *r.cam);
            ffi::mjv_defaultPerturb(&mut *r.pert);
            ffi::mjv_defaultScene(&mut *r.scn);
            ffi::mjr_defaultContext(&mut *r.con);
            let m = r.own.as_ptr();
            let (scn, con) = (&mut *r.scn as *mut _, &mut *r.con as *mut _);
            // docs/original-d3il.md §01.6: a visual scene with at most 1000 geoms.
            guarded(|| ffi::mjv_makeScene(m, scn, 1000))?;
            // No light in our scenes casts shadows and no material reflects,
            // so these passes would only cost time (same pixels).
            r.scn.flags[ffi::mjtRndFlag__mjRND_SHADOW as usize] = 0;
            r.scn.flags[ffi::mjtRndFlag__mjRND_REFLECTION as usize] = 0;
            guarded(|| ffi::mjr_makeContext(m, con, ffi::mjtFontScale__mjFONTSCALE_150 as i32))?;
            if r.con.offWidth < width as i32 || r.con.offHeight < height as i32 {
                return Err(MjError::Render(format!(
                    "the offscreen buffer is {}x{} but {width}x{height} was requested; raise visual/global offwidth/offheight",
                    r.con.offWidth, r.con.offHeight
                )));
            }
            ffi::mjr_setBuffer(ffi::mjtFramebuffer__mjFB_OFFSCREEN as i32, con);
            r.planes = Some(PlaneLists::new(m, &r.con));
            Ok(r)
        }
    }

    pub fn model(&self) -> &Arc<Model> {
        &self.model
    }

    /// Which of the process's EGL displays (each one llvmpipe screen) this
    /// renderer draws on: renderers that exist at the same time get
    /// different ones while Mesa can make them (see [`Lease`]).
    pub fn display_slot(&self) -> usize {
        self.lease.slot
    }

    pub fn width(&self) -> usize {
        self.width
    }

    /// Side of the shadow map the GL context allocated (0: none, as shadows
    /// are never drawn).
    pub fn shadow_map_size(&self) -> usize {
        self.con.shadowSize.max(0) as usize
    }

    pub fn height(&self) -> usize {
        self.height
    }

    /// How many geoms the last frame left out because the table top hides
    /// them from the camera (the frame is the same without them).
    pub fn hidden_geoms(&self) -> usize {
        self.hidden
    }

    /// Draws the geoms the table top hides too (`true`), as MuJoCo would;
    /// for tests that compare the frames both ways. Default `false`.
    pub fn keep_hidden_geoms(&mut self, keep: bool) {
        self.keep_hidden = keep;
    }

    /// Renders fixed camera `camera` (a camera id of the model) from the
    /// current derived quantities of `data` (no `mj_forward`, like the
    /// reference) into `rgb`: width × height × 3 bytes, rows bottom-up, as
    /// OpenGL returns them.
    pub fn render_raw(
        &mut self,
        data: &mut Data,
        camera: usize,
        rgb: &mut [u8],
    ) -> Result<(), MjError> {
        if !Arc::ptr_eq(&self.model, data.model()) {
            return Err(MjError::Input(
                "the renderer was made for a different model than the data's".into(),
            ));
        }
        let ncam = self.model.raw().ncam as usize;
        if camera >= ncam {
            return Err(MjError::Input(format!(
                "camera id {camera} out of range (the model has {ncam})"
            )));
        }
        let n = self.width * self.height * 3;
        if rgb.len() != n {
            return Err(MjError::Input(format!(
                "pixel buffer has {} bytes; {}x{}x3 = {n} expected",
                rgb.len(),
                self.width,
                self.height
            )));
        }
        self.cam.type_ = ffi::mjtCamera__mjCAMERA_FIXED as i32;
        self.cam.fixedcamid = camera as i32;
        let viewport = ffi::mjrRect {
            left: 0,
            bottom: 0,
            width: self.width as i32,
            height: self.height as i32,
        };
        let m = self.own.as_ptr();
        let d = data.ptr.as_ptr();
        let (opt, pert, cam) = (
            &*self.opt as *const _,
            &*self.pert as *const _,
            &mut *self.cam as *mut _,
        );
        let (scn, con) = (&mut *self.scn as *mut _, &mut *self.con as *mut _);
        let planes = self.planes.as_mut().map(|p| p as *mut PlaneLists);
        let hidden = &mut self.hidden as *mut usize;
        let keep_hidden = self.keep_hidden;
        let aspect = viewport.width as f32 / viewport.height as f32;
        let dpy = self.lease.dpy;
        let (surface, ctx) = (self.surface, self.ctx);
        // SAFETY: all pointers are valid and owned by `self`/`data`; the
        // buffer size was checked; the context is made current first (cheap
        // when already current on this thread).
        unsafe {
            if eglMakeCurrent(dpy, surface, surface, ctx) == 0 {
                return Err(egl_error("eglMakeCurrent"));
            }
            guarded(|| {
                ffi::mjv_updateScene(m, d, opt, pert, cam, ffi::mjtCatBit__mjCAT_ALL as i32, scn);
                *hidden = 0;
                if let Some(view) = Frustum::of(&(*scn).camera[0], aspect) {
                    cull_outside_frustum(&mut *scn, &view);
                    if !keep_hidden {
                        *hidden = cull_under_slabs(&mut *scn);
                    }
                    if let Some(p) = planes {
                        (*p).select(camera, &*scn, &view, &mut *con);
                    }
                }
                ffi::mjr_setBuffer(ffi::mjtFramebuffer__mjFB_OFFSCREEN as i32, con);
                ffi::mjr_render(viewport, scn, con);
                if let Some(p) = planes {
                    (*p).restore(&mut *con);
                }
                ffi::mjr_readPixels(rgb.as_mut_ptr(), std::ptr::null_mut(), viewport, con);
            })
        }
    }
}

impl Drop for Renderer {
    fn drop(&mut self) {
        // SAFETY: we own these objects; MuJoCo's free functions need the
        // context current.
        unsafe {
            eglMakeCurrent(self.lease.dpy, self.surface, self.surface, self.ctx);
            if let Some(p) = &mut self.planes {
                p.free();
            }
            ffi::mjr_freeContext(&mut *self.con);
            ffi::mjv_freeScene(&mut *self.scn);
            eglMakeCurrent(
                self.lease.dpy,
                std::ptr::null_mut(),
                std::ptr::null_mut(),
                std::ptr::null_mut(),
            );
            eglDestroyContext(self.lease.dpy, self.ctx);
            eglDestroySurface(self.lease.dpy, self.surface);
            ffi::mj_deleteModel(self.own.as_ptr());
        }
    }
}
