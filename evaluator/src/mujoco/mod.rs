//! Thin safe wrapper over the MuJoCo 2.2 C API. This module holds all of the
//! project's `unsafe` code; everything outside it uses [`Model`] and [`Data`].
//!
//! * [`Model`] is compiled from MJCF strings through MuJoCo's virtual file
//!   system, so nothing touches the disk and includes resolve in memory.
//! * [`Data`] is one simulation state (one per rollout). It is `Send`, and many
//!   `Data` can share one `Arc<Model>` across threads (the model is read-only).
//! * MuJoCo's default error handler exits the process. We install our own
//!   handlers before the first call: warnings are recorded, errors unwind as a
//!   Rust panic that [`Data::step`] catches and turns into [`MjError::Runtime`].

#[allow(
    non_camel_case_types,
    non_snake_case,
    non_upper_case_globals,
    dead_code,
    unused_imports,
    clippy::all,
    unsafe_op_in_unsafe_fn
)]
mod bindings;
mod egl;
mod render;
mod view;

pub use render::{egl_vendor, set_llvmpipe_defaults, Renderer};

use std::ffi::{CStr, CString};
use std::ptr::NonNull;
use std::sync::{Arc, Once};

use bindings as ffi;

/// Errors from the MuJoCo layer.
#[derive(Debug, thiserror::Error)]
pub enum MjError {
    #[error("MuJoCo could not compile the model: {0}")]
    Compile(String),
    #[error("no {kind} named `{name}` in the model")]
    UnknownName { kind: &'static str, name: String },
    #[error("MuJoCo runtime error: {0}")]
    Runtime(String),
    #[error("invalid model input: {0}")]
    Input(String),
    #[error("rendering failed: {0}")]
    Render(String),
}

/// Kinds of named objects we look up.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ObjKind {
    Body,
    Joint,
    Geom,
    Actuator,
    Site,
    Camera,
}

impl ObjKind {
    fn raw(self) -> i32 {
        (match self {
            ObjKind::Body => ffi::mjtObj__mjOBJ_BODY,
            ObjKind::Joint => ffi::mjtObj__mjOBJ_JOINT,
            ObjKind::Geom => ffi::mjtObj__mjOBJ_GEOM,
            ObjKind::Actuator => ffi::mjtObj__mjOBJ_ACTUATOR,
            ObjKind::Site => ffi::mjtObj__mjOBJ_SITE,
            ObjKind::Camera => ffi::mjtObj__mjOBJ_CAMERA,
        }) as i32
    }
    fn label(self) -> &'static str {
        match self {
            ObjKind::Body => "body",
            ObjKind::Joint => "joint",
            ObjKind::Geom => "geom",
            ObjKind::Actuator => "actuator",
            ObjKind::Site => "site",
            ObjKind::Camera => "camera",
        }
    }
}

static HANDLERS: Once = Once::new();

thread_local! {
    static WARNINGS: std::cell::RefCell<Vec<String>> = const { std::cell::RefCell::new(Vec::new()) };
}

/// Marker payload for panics raised by MuJoCo's error callback.
struct MujocoPanic(String);

unsafe extern "C-unwind" fn on_error(msg: *const std::os::raw::c_char) {
    let text = if msg.is_null() {
        "unknown MuJoCo error".to_string()
    } else {
        CStr::from_ptr(msg).to_string_lossy().into_owned()
    };
    // Said on stderr first: if the unwind itself cannot start (an allocation
    // failure under the worker's address-space limit leaves no memory for
    // it), the process aborts, and the sandbox parent reads this line to name
    // the memory limit instead of reporting a bare SIGABRT.
    eprintln!("MuJoCo error: {text}");
    // Unwind back to the Rust frame that called into MuJoCo (see `guarded`).
    std::panic::panic_any(MujocoPanic(text));
}

unsafe extern "C" fn on_warning(msg: *const std::os::raw::c_char) {
    if msg.is_null() {
        return;
    }
    let text = CStr::from_ptr(msg).to_string_lossy().into_owned();
    WARNINGS.with(|w| {
        let mut w = w.borrow_mut();
        if w.len() < 64 {
            w.push(text);
        }
    });
}

/// Installs our error and warning handlers (idempotent). Called by every
/// constructor; the CLI also calls it at start-up.
pub fn install_handlers() {
    HANDLERS.call_once(|| unsafe {
        // SAFETY: written once, before any other MuJoCo call of this process
        // through this module. The error handler has the C-unwind ABI so that
        // the panic can cross the C frames back into `guarded`.
        let err: unsafe extern "C-unwind" fn(*const std::os::raw::c_char) = on_error;
        ffi::mju_user_error = Some(std::mem::transmute::<
            unsafe extern "C-unwind" fn(*const std::os::raw::c_char),
            unsafe extern "C" fn(*const std::os::raw::c_char),
        >(err));
        ffi::mju_user_warning = Some(on_warning);
    });
}

/// Warnings MuJoCo raised on this thread since the last call.
pub fn take_warnings() -> Vec<String> {
    WARNINGS.with(|w| std::mem::take(&mut *w.borrow_mut()))
}

/// Runs `f`, turning a MuJoCo error (which unwinds out of our handler) into `Err`.
fn guarded<T>(f: impl FnOnce() -> T) -> Result<T, MjError> {
    match std::panic::catch_unwind(std::panic::AssertUnwindSafe(f)) {
        Ok(v) => Ok(v),
        Err(payload) => match payload.downcast::<MujocoPanic>() {
            Ok(p) => Err(MjError::Runtime(p.0)),
            Err(other) => std::panic::resume_unwind(other),
        },
    }
}

/// MuJoCo's version string, e.g. "2.2.2".
pub fn version() -> String {
    install_handlers();
    // SAFETY: returns a pointer to a static string.
    unsafe { CStr::from_ptr(ffi::mj_versionString()) }
        .to_string_lossy()
        .into_owned()
}

/// A compiled model. Read-only after compilation, shared between threads.
pub struct Model {
    ptr: NonNull<ffi::mjModel>,
}

// SAFETY: an mjModel is plain memory that MuJoCo only reads during simulation.
unsafe impl Send for Model {}
unsafe impl Sync for Model {}

impl Drop for Model {
    fn drop(&mut self) {
        // SAFETY: we own the pointer, created by mj_loadXML.
        unsafe { ffi::mj_deleteModel(self.ptr.as_ptr()) }
    }
}

fn c_name(name: &str) -> Result<CString, MjError> {
    CString::new(name).map_err(|_| MjError::Input(format!("name `{name}` contains a NUL byte")))
}

struct Vfs(Box<std::mem::MaybeUninit<ffi::mjVFS>>);

impl Vfs {
    fn new() -> Vfs {
        // mjVFS is ~2 MB: keep it off the stack.
        let mut b = Box::<ffi::mjVFS>::new_uninit();
        // SAFETY: mj_defaultVFS initialises every field.
        unsafe { ffi::mj_defaultVFS(b.as_mut_ptr()) };
        Vfs(b)
    }
    fn ptr(&mut self) -> *mut ffi::mjVFS {
        self.0.as_mut_ptr()
    }
    fn add(&mut self, name: &str, contents: &[u8]) -> Result<(), MjError> {
        let cname = c_name(name)?;
        if name.len() >= 1000 {
            return Err(MjError::Input(format!("file name `{name}` is too long")));
        }
        let size = i32::try_from(contents.len())
            .map_err(|_| MjError::Input(format!("file `{name}` is too large")))?;
        // SAFETY: the VFS is initialised; mj_makeEmptyFileVFS allocates `size` bytes.
        unsafe {
            let rc = ffi::mj_makeEmptyFileVFS(self.ptr(), cname.as_ptr(), size);
            match rc {
                0 => {}
                1 => return Err(MjError::Input("too many files for MuJoCo's VFS".into())),
                _ => return Err(MjError::Input(format!("file `{name}` given twice"))),
            }
            let vfs = &mut *self.ptr();
            let idx = (vfs.nfile - 1) as usize;
            std::ptr::copy_nonoverlapping(
                contents.as_ptr(),
                vfs.filedata[idx] as *mut u8,
                contents.len(),
            );
        }
        Ok(())
    }
}

impl Drop for Vfs {
    fn drop(&mut self) {
        // SAFETY: frees the buffers allocated by mj_makeEmptyFileVFS.
        unsafe { ffi::mj_deleteVFS(self.ptr()) }
    }
}

macro_rules! model_slice {
    ($(#[$doc:meta])* $name:ident, $field:ident, $ty:ty, $len:expr) => {
        $(#[$doc])*
        pub fn $name(&self) -> &[$ty] {
            let m = self.raw();
            // SAFETY: MuJoCo allocates `$len` elements for this field.
            unsafe { std::slice::from_raw_parts(m.$field, ($len)(m) as usize) }
        }
    };
}

impl Model {
    /// Compiles `main_xml`; `files` are (name, contents) pairs that `<include>`
    /// elements of the main file may refer to.
    pub fn from_xml(main_xml: &str, files: &[(&str, &str)]) -> Result<Model, MjError> {
        install_handlers();
        let mut vfs = Vfs::new();
        const MAIN: &str = "d3il_scene.xml";
        vfs.add(MAIN, main_xml.as_bytes())?;
        for (name, contents) in files {
            vfs.add(name, contents.as_bytes())?;
        }
        let cmain = c_name(MAIN)?;
        let mut err = vec![0 as std::os::raw::c_char; 1024];
        let raw = guarded(|| unsafe {
            // SAFETY: valid VFS and error buffer; MuJoCo copies what it needs.
            ffi::mj_loadXML(
                cmain.as_ptr(),
                vfs.ptr(),
                err.as_mut_ptr(),
                err.len() as i32,
            )
        })?;
        // SAFETY: the buffer is NUL-terminated by MuJoCo (or still all zeros).
        let msg = unsafe { CStr::from_ptr(err.as_ptr()) }
            .to_string_lossy()
            .into_owned();
        match NonNull::new(raw) {
            Some(ptr) => Ok(Model { ptr }),
            None => Err(MjError::Compile(if msg.is_empty() {
                "unknown error".into()
            } else {
                msg
            })),
        }
    }

    fn raw(&self) -> &ffi::mjModel {
        // SAFETY: valid for our lifetime.
        unsafe { self.ptr.as_ref() }
    }

    pub fn nq(&self) -> usize {
        self.raw().nq as usize
    }
    pub fn nv(&self) -> usize {
        self.raw().nv as usize
    }
    pub fn nu(&self) -> usize {
        self.raw().nu as usize
    }
    pub fn nbody(&self) -> usize {
        self.raw().nbody as usize
    }
    pub fn ngeom(&self) -> usize {
        self.raw().ngeom as usize
    }
    /// Vertical field of view of camera `camera`, degrees.
    pub fn cam_fovy(&self, camera: usize) -> f64 {
        let m = self.raw();
        assert!(camera < m.ncam as usize, "camera id out of range");
        // SAFETY: `cam_fovy` holds `ncam` values; the index was checked.
        unsafe { *m.cam_fovy.add(camera) }
    }

    pub fn timestep(&self) -> f64 {
        self.raw().opt.timestep
    }

    /// Id of a named object, or an error naming what is missing.
    pub fn id(&self, kind: ObjKind, name: &str) -> Result<usize, MjError> {
        let cname = c_name(name)?;
        // SAFETY: valid model and NUL-terminated name.
        let id = unsafe { ffi::mj_name2id(self.ptr.as_ptr(), kind.raw(), cname.as_ptr()) };
        if id < 0 {
            Err(MjError::UnknownName {
                kind: kind.label(),
                name: name.to_string(),
            })
        } else {
            Ok(id as usize)
        }
    }

    model_slice!(
        /// Joint qpos addresses.
        jnt_qposadr, jnt_qposadr, i32, |m: &ffi::mjModel| m.njnt);
    model_slice!(
        /// Joint dof addresses.
        jnt_dofadr, jnt_dofadr, i32, |m: &ffi::mjModel| m.njnt);
    model_slice!(body_mass, body_mass, f64, |m: &ffi::mjModel| m.nbody);
    model_slice!(
        /// Body inertias (3 per body).
        body_inertia, body_inertia, f64, |m: &ffi::mjModel| 3 * m.nbody);
    model_slice!(
        /// Body COM positions in the body frame (3 per body).
        body_ipos, body_ipos, f64, |m: &ffi::mjModel| 3 * m.nbody);
    model_slice!(
        /// Body positions relative to the parent (3 per body).
        body_pos, body_pos, f64, |m: &ffi::mjModel| 3 * m.nbody);
    model_slice!(
        /// Body quaternions relative to the parent (4 per body, wxyz).
        body_quat, body_quat, f64, |m: &ffi::mjModel| 4 * m.nbody);
    model_slice!(
        /// Geom sizes (3 per geom).
        geom_size, geom_size, f64, |m: &ffi::mjModel| 3 * m.ngeom);
    model_slice!(
        /// Mocap index of each body (-1 for bodies that are not mocap bodies).
        body_mocapid, body_mocapid, i32, |m: &ffi::mjModel| m.nbody);

    /// qpos address of the named joint.
    pub fn joint_qpos_addr(&self, joint: &str) -> Result<usize, MjError> {
        Ok(self.jnt_qposadr()[self.id(ObjKind::Joint, joint)?] as usize)
    }

    /// dof address of the named joint.
    pub fn joint_dof_addr(&self, joint: &str) -> Result<usize, MjError> {
        Ok(self.jnt_dofadr()[self.id(ObjKind::Joint, joint)?] as usize)
    }

    model_slice!(
        /// Body id of each geom.
        geom_bodyid, geom_bodyid, i32, |m: &ffi::mjModel| m.ngeom);
    model_slice!(
        /// Geom contact priorities.
        geom_priority, geom_priority, i32, |m: &ffi::mjModel| m.ngeom);
    model_slice!(
        /// Geom friction (sliding, torsional, rolling; 3 per geom).
        geom_friction, geom_friction, f64, |m: &ffi::mjModel| 3 * m.ngeom);

    /// Changes the dynamics of a model that no `Data` uses yet (the
    /// robustness track's dynamics axis): scales the listed bodies' mass and
    /// inertia by `mass`, gives their geoms `friction` (sliding, as
    /// `(geom, value)`) and `priority` (`(geom, value)`), then recomputes the
    /// constants MuJoCo derives from masses (`mj_setConst`). `Arc::get_mut`
    /// on the shared model is what makes "no `Data` uses it" hold.
    pub fn perturb_dynamics(
        &mut self,
        bodies: &[usize],
        mass: f64,
        friction: &[(usize, f64)],
        priority: &[(usize, i32)],
    ) -> Result<(), MjError> {
        let (nbody, ngeom) = (self.raw().nbody as usize, self.raw().ngeom as usize);
        if let Some(b) = bodies.iter().find(|&&b| b >= nbody) {
            return Err(MjError::Input(format!("body id {b} out of range")));
        }
        if let Some(g) = friction
            .iter()
            .map(|f| f.0)
            .chain(priority.iter().map(|p| p.0))
            .find(|&g| g >= ngeom)
        {
            return Err(MjError::Input(format!("geom id {g} out of range")));
        }
        // SAFETY: `&mut self` is the only reference to the model; the ids
        // were checked against the arrays' lengths above.
        unsafe {
            let m = self.ptr.as_mut();
            for &b in bodies {
                *m.body_mass.add(b) *= mass;
                for k in 0..3 {
                    *m.body_inertia.add(3 * b + k) *= mass;
                }
            }
            for &(g, f) in friction {
                *m.geom_friction.add(3 * g) = f;
            }
            for &(g, p) in priority {
                *m.geom_priority.add(g) = p;
            }
        }
        install_handlers();
        let ptr = self.ptr.as_ptr();
        guarded(|| unsafe {
            // SAFETY: a scratch mjData of this model, deleted right after
            // mj_setConst has used it.
            let d = ffi::mj_makeData(ptr);
            if !d.is_null() {
                ffi::mj_setConst(ptr, d);
                ffi::mj_deleteData(d);
            }
        })
    }

    /// The image axes of the robustness suites (`crate::perturb`): each of
    /// `cameras` (id, new `cam_pos`, new `cam_quat`) set; every light's
    /// ambient, diffuse and specular colour scaled by `light_scale` and its
    /// direction replaced by the one `light_dir` maps it to. Then
    /// `mj_setConst`, so the derived reference poses agree.
    pub fn perturb_view(
        &mut self,
        cameras: &[(usize, [f64; 3], [f64; 4])],
        light_scale: f32,
        light_dir: &dyn Fn([f64; 3]) -> [f64; 3],
    ) -> Result<(), MjError> {
        let (ncam, nlight) = (self.raw().ncam as usize, self.raw().nlight as usize);
        if let Some(c) = cameras.iter().find(|c| c.0 >= ncam) {
            return Err(MjError::Input(format!("camera id {} out of range", c.0)));
        }
        // SAFETY: `&mut self` is the only reference to the model; the camera
        // ids were checked above, the light loop stays below `nlight`.
        unsafe {
            let m = self.ptr.as_mut();
            for &(c, pos, quat) in cameras {
                for (k, v) in pos.into_iter().enumerate() {
                    *m.cam_pos.add(3 * c + k) = v;
                }
                for (k, v) in quat.into_iter().enumerate() {
                    *m.cam_quat.add(4 * c + k) = v;
                }
            }
            for l in 0..nlight {
                for k in 0..3 {
                    *m.light_ambient.add(3 * l + k) *= light_scale;
                    *m.light_diffuse.add(3 * l + k) *= light_scale;
                    *m.light_specular.add(3 * l + k) *= light_scale;
                }
                let d = [0, 1, 2].map(|k| *m.light_dir.add(3 * l + k));
                for (k, v) in light_dir(d).into_iter().enumerate() {
                    *m.light_dir.add(3 * l + k) = v;
                }
            }
        }
        install_handlers();
        let ptr = self.ptr.as_ptr();
        guarded(|| unsafe {
            // SAFETY: a scratch mjData of this model, deleted right after
            // mj_setConst has used it.
            let d = ffi::mj_makeData(ptr);
            if !d.is_null() {
                ffi::mj_setConst(ptr, d);
                ffi::mj_deleteData(d);
            }
        })
    }

    /// A camera's pose relative to its body: (`cam_pos`, `cam_quat`).
    pub fn cam_local_pose(&self, camera: usize) -> ([f64; 3], [f64; 4]) {
        let m = self.raw();
        assert!(camera < m.ncam as usize, "camera id {camera} out of range");
        // SAFETY: checked against ncam; MuJoCo allocates 3 and 4 per camera.
        unsafe {
            (
                [0, 1, 2].map(|k| *m.cam_pos.add(3 * camera + k)),
                [0, 1, 2, 3].map(|k| *m.cam_quat.add(4 * camera + k)),
            )
        }
    }

    /// Every light's (diffuse colour, direction), in the light's body frame.
    pub fn lights(&self) -> Vec<([f32; 3], [f64; 3])> {
        let m = self.raw();
        // SAFETY: MuJoCo allocates 3 entries per light for both fields.
        (0..m.nlight as usize)
            .map(|l| unsafe {
                (
                    [0, 1, 2].map(|k| *m.light_diffuse.add(3 * l + k)),
                    [0, 1, 2].map(|k| *m.light_dir.add(3 * l + k)),
                )
            })
            .collect()
    }

    /// Pointer for the rendering module (same crate, still inside the binding).
    #[allow(dead_code)]
    pub(crate) fn as_ptr(&self) -> *const ffi::mjModel {
        self.ptr.as_ptr()
    }
}

/// One contact from MuJoCo's current contact list.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Contact {
    pub geom1: usize,
    pub geom2: usize,
    pub dist: f64,
    pub pos: [f64; 3],
}

/// One simulation state.
pub struct Data {
    ptr: NonNull<ffi::mjData>,
    model: Arc<Model>,
}

// SAFETY: an mjData is owned exclusively by this value; MuJoCo keeps no
// thread-local references to it.
unsafe impl Send for Data {}

impl Drop for Data {
    fn drop(&mut self) {
        // SAFETY: we own the pointer, created by mj_makeData.
        unsafe { ffi::mj_deleteData(self.ptr.as_ptr()) }
    }
}

macro_rules! data_slice {
    ($(#[$doc:meta])* $name:ident, $name_mut:ident, $field:ident, $len:expr) => {
        $(#[$doc])*
        pub fn $name(&self) -> &[f64] {
            let (m, d) = (self.model.raw(), self.raw());
            // SAFETY: MuJoCo allocates `$len` elements for this field.
            unsafe { std::slice::from_raw_parts(d.$field, ($len)(m) as usize) }
        }
        $(#[$doc])*
        pub fn $name_mut(&mut self) -> &mut [f64] {
            let n = ($len)(self.model.raw()) as usize;
            // SAFETY: as above; &mut self gives exclusive access.
            unsafe { std::slice::from_raw_parts_mut(self.ptr.as_mut().$field, n) }
        }
    };
}

impl Data {
    pub fn new(model: Arc<Model>) -> Result<Data, MjError> {
        install_handlers();
        let raw = guarded(|| unsafe { ffi::mj_makeData(model.ptr.as_ptr()) })?;
        let ptr = NonNull::new(raw)
            .ok_or_else(|| MjError::Runtime("mj_makeData could not allocate".into()))?;
        Ok(Data { ptr, model })
    }

    pub fn model(&self) -> &Arc<Model> {
        &self.model
    }

    fn raw(&self) -> &ffi::mjData {
        // SAFETY: valid for our lifetime.
        unsafe { self.ptr.as_ref() }
    }

    /// One `mj_step`.
    pub fn step(&mut self) -> Result<(), MjError> {
        let (m, d) = (self.model.ptr.as_ptr(), self.ptr.as_ptr());
        // SAFETY: valid model/data pair.
        guarded(|| unsafe { ffi::mj_step(m, d) })
    }

    /// `mj_forward`.
    pub fn forward(&mut self) -> Result<(), MjError> {
        let (m, d) = (self.model.ptr.as_ptr(), self.ptr.as_ptr());
        // SAFETY: valid model/data pair.
        guarded(|| unsafe { ffi::mj_forward(m, d) })
    }

    /// `mj_resetData`.
    pub fn reset(&mut self) {
        // SAFETY: valid model/data pair; resetting cannot fail.
        unsafe { ffi::mj_resetData(self.model.ptr.as_ptr(), self.ptr.as_ptr()) }
    }

    pub fn time(&self) -> f64 {
        self.raw().time
    }

    data_slice!(qpos, qpos_mut, qpos, |m: &ffi::mjModel| m.nq);
    data_slice!(qvel, qvel_mut, qvel, |m: &ffi::mjModel| m.nv);
    data_slice!(ctrl, ctrl_mut, ctrl, |m: &ffi::mjModel| m.nu);
    data_slice!(
        /// Bias forces (Coriolis, centrifugal, gravity) as left by the last step/forward.
        qfrc_bias, qfrc_bias_mut, qfrc_bias, |m: &ffi::mjModel| m.nv);
    data_slice!(
        /// Body world positions, 3 per body, from the last kinematics pass.
        xpos_all, xpos_all_mut, xpos, |m: &ffi::mjModel| 3 * m.nbody);
    data_slice!(
        /// Body world quaternions (wxyz), 4 per body.
        xquat_all, xquat_all_mut, xquat, |m: &ffi::mjModel| 4 * m.nbody);
    data_slice!(
        /// Mocap body positions, 3 per mocap body. Per-Data poses for bodies the
        /// model marks `mocap="true"` (e.g. Aligning's target), so a rollout can
        /// move them without writing the shared read-only Model.
        mocap_pos, mocap_pos_mut, mocap_pos, |m: &ffi::mjModel| 3 * m.nmocap);
    data_slice!(
        /// Mocap body quaternions (wxyz), 4 per mocap body.
        mocap_quat, mocap_quat_mut, mocap_quat, |m: &ffi::mjModel| 4 * m.nmocap);

    data_slice!(
        /// Camera world positions, 3 per camera.
        cam_xpos_all, cam_xpos_all_mut, cam_xpos, |m: &ffi::mjModel| 3 * m.ncam);
    data_slice!(
        /// Camera world orientations, row-major 3x3 per camera.
        cam_xmat_all, cam_xmat_all_mut, cam_xmat, |m: &ffi::mjModel| 9 * m.ncam);

    pub fn cam_xpos(&self, camera: usize) -> [f64; 3] {
        let s = &self.cam_xpos_all()[3 * camera..3 * camera + 3];
        [s[0], s[1], s[2]]
    }

    pub fn cam_xmat(&self, camera: usize) -> [f64; 9] {
        let mut r = [0.0; 9];
        r.copy_from_slice(&self.cam_xmat_all()[9 * camera..9 * camera + 9]);
        r
    }

    pub fn xpos(&self, body: usize) -> [f64; 3] {
        let s = &self.xpos_all()[3 * body..3 * body + 3];
        [s[0], s[1], s[2]]
    }

    pub fn xquat(&self, body: usize) -> [f64; 4] {
        let s = &self.xquat_all()[4 * body..4 * body + 4];
        [s[0], s[1], s[2], s[3]]
    }

    /// Contacts found by the last collision detection.
    pub fn contacts(&self) -> impl Iterator<Item = Contact> + '_ {
        let d = self.raw();
        let n = d.ncon.max(0) as usize;
        // SAFETY: `contact` holds `ncon` valid entries.
        let list = unsafe { std::slice::from_raw_parts(d.contact, n) };
        list.iter().map(|c| Contact {
            geom1: c.geom1 as usize,
            geom2: c.geom2 as usize,
            dist: c.dist,
            pos: c.pos,
        })
    }

    /// True if the current contact list holds the pair (a, b) in either order.
    pub fn has_contact(&self, a: usize, b: usize) -> bool {
        self.contacts()
            .any(|c| (c.geom1 == a && c.geom2 == b) || (c.geom1 == b && c.geom2 == a))
    }

    /// Number of MuJoCo warnings of each kind raised in this data.
    pub fn warning_count(&self) -> i32 {
        self.raw().warning.iter().map(|w| w.number).sum()
    }
}

#[cfg(test)]
mod tests;
