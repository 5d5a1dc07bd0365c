//! What a camera can see, for leaving out of a frame what covers no pixel:
//! model geoms entirely outside the view ([`cull_outside_frustum`]), model
//! geoms entirely hidden under the table top ([`cull_under_slabs`]) and the
//! cells of an infinite ground plane's grid outside the view ([`PlaneLists`]).
//! All only ever keep too much, so frames are identical (docs/images.md).

use super::egl::eglGetProcAddress;
use super::ffi;
use std::ffi::c_void;

/// A camera's view volume: the four side planes through the eye, each
/// widened by 10% (so tests against them only ever keep too much), and the
/// near plane. The far plane is not used.
pub(super) struct Frustum {
    eye: [f32; 3],
    /// Camera frame: right, up, forward (world coordinates).
    axes: [[f32; 3]; 3],
    near: f32,
    /// Outward unit normals of the side planes, camera frame (z forward).
    sides: [[f32; 3]; 4],
}

impl Frustum {
    /// The view volume of the scene's camera for a viewport of this aspect
    /// ratio; None for a degenerate camera (nothing is left out then).
    pub(super) fn of(c: &ffi::mjvGLCamera, aspect: f32) -> Option<Frustum> {
        let (f, u) = (c.forward, c.up);
        let right = [
            f[1] * u[2] - f[2] * u[1],
            f[2] * u[0] - f[0] * u[2],
            f[0] * u[1] - f[1] * u[0],
        ];
        let near = c.frustum_near;
        if near.is_nan() || near <= 0.0 || aspect.is_nan() || aspect <= 0.0 {
            return None;
        }
        let half_w = 0.55 * aspect * (c.frustum_top - c.frustum_bottom);
        let half_h = 0.55 * (c.frustum_top - c.frustum_bottom);
        let mid_y = 0.5 * (c.frustum_top + c.frustum_bottom);
        let (l, r) = (c.frustum_center - half_w, c.frustum_center + half_w);
        let (b, t) = (mid_y - half_h, mid_y + half_h);
        let sides = [
            [near, 0.0, -r],
            [-near, 0.0, l],
            [0.0, near, -t],
            [0.0, -near, b],
        ]
        .map(|n| {
            let len = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
            [n[0] / len, n[1] / len, n[2] / len]
        });
        Some(Frustum {
            eye: c.pos,
            axes: [right, u, f],
            near,
            sides,
        })
    }

    /// Whether a sphere lies entirely outside the view volume.
    fn excludes_sphere(&self, centre: [f32; 3], radius: f32) -> bool {
        let d = [
            centre[0] - self.eye[0],
            centre[1] - self.eye[1],
            centre[2] - self.eye[2],
        ];
        let p = self.axes.map(|a| d[0] * a[0] + d[1] * a[1] + d[2] * a[2]);
        p[2] < self.near - radius
            || self
                .sides
                .iter()
                .any(|n| n[0] * p[0] + n[1] * p[1] + n[2] * p[2] > radius)
    }

    /// The view volume as half-spaces `n · (P − eye) ≤ 0` in world
    /// coordinates: the four sides, and "in front of the eye" (a plane
    /// through the eye, wider than the near plane).
    fn half_spaces(&self) -> [[f64; 3]; 5] {
        let world = |v: [f32; 3]| {
            let a = &self.axes;
            [0, 1, 2].map(|k| (v[0] * a[0][k] + v[1] * a[1][k] + v[2] * a[2][k]) as f64)
        };
        let s = self.sides;
        [
            world(s[0]),
            world(s[1]),
            world(s[2]),
            world(s[3]),
            world([0.0, 0.0, -1.0]),
        ]
    }
}

/// Drops from the scene every model geom whose bounding sphere lies entirely
/// outside the camera's view, before `mjr_render` draws it. Such a geom
/// covers no pixel (no shadows or reflections are drawn), so the frame is
/// identical; llvmpipe would otherwise run every triangle of it through
/// vertex processing and clipping (a capsule is 2688 triangles at MuJoCo's
/// default quality). Planes and decorative geoms are always kept.
pub(super) fn cull_outside_frustum(scn: &mut ffi::mjvScene, view: &Frustum) {
    drop_model_geoms(scn, |g| view.excludes_sphere(g.pos, g.modelrbound));
}

/// The scene's geoms (as mjv_updateScene filled them).
fn scene_geoms(scn: &mut ffi::mjvScene) -> &mut [ffi::mjvGeom] {
    let n = scn.ngeom.max(0) as usize;
    if n == 0 || scn.geoms.is_null() {
        return &mut [];
    }
    // SAFETY: mjv_updateScene filled `ngeom` entries of `geoms`.
    unsafe { std::slice::from_raw_parts_mut(scn.geoms, n) }
}

/// Removes from the scene the model geoms (not planes, with a bounding
/// sphere; decorative geoms are always kept) for which `drop` holds, keeping
/// the others in order; returns how many were removed.
fn drop_model_geoms(scn: &mut ffi::mjvScene, mut drop: impl FnMut(&ffi::mjvGeom) -> bool) -> usize {
    let geoms = scene_geoms(scn);
    let n = geoms.len();
    let mut kept = 0;
    for i in 0..n {
        let g = geoms[i];
        let cullable = g.objtype == ffi::mjtObj__mjOBJ_GEOM as i32
            && g.type_ != ffi::mjtGeom__mjGEOM_PLANE as i32
            && g.modelrbound > 0.0;
        if !(cullable && drop(&g)) {
            geoms[kept] = g;
            kept += 1;
        }
    }
    if n > 0 {
        scn.ngeom = kept as i32;
    }
    n - kept
}

/// How far inside a slab's top face, and below it, a hidden geom must stay
/// (metres): far more than llvmpipe's vertex snapping (1/256 pixel) or
/// float rounding can move an edge, so a geom counted as hidden is hidden at
/// every sample.
const SLAB_MARGIN: f64 = 0.005;

/// The top face of an opaque slab: a static, opaque, axis-aligned box geom of
/// the scene (the table), shrunk by [`SLAB_MARGIN`].
#[derive(Debug, Clone, Copy, PartialEq)]
struct TopFace {
    z: f64,
    x: [f64; 2],
    y: [f64; 2],
}

impl TopFace {
    fn of(g: &ffi::mjvGeom) -> Option<TopFace> {
        let axis_aligned = g
            .mat
            .iter()
            .enumerate()
            .all(|(k, v)| (*v as f64 - if k % 4 == 0 { 1.0 } else { 0.0 }).abs() < 1e-6);
        let slab = g.objtype == ffi::mjtObj__mjOBJ_GEOM as i32
            && g.type_ == ffi::mjtGeom__mjGEOM_BOX as i32
            && g.category == ffi::mjtCatBit__mjCAT_STATIC as i32
            && g.rgba[3] >= 1.0
            && g.transparent == 0
            && axis_aligned;
        let [p, s] = [g.pos, g.size].map(|v| v.map(f64::from));
        (slab && s[0] > SLAB_MARGIN && s[1] > SLAB_MARGIN).then(|| TopFace {
            z: p[2] + s[2],
            x: [p[0] - s[0] + SLAB_MARGIN, p[0] + s[0] - SLAB_MARGIN],
            y: [p[1] - s[1] + SLAB_MARGIN, p[1] + s[1] - SLAB_MARGIN],
        })
    }

    /// Whether every line of sight from `eye` to the sphere crosses this face
    /// first: the eye is above it, the sphere below it, and the face's
    /// (convex) rectangle holds the shadow that the sphere's bounding cube
    /// casts on its plane from the eye (the cube is convex too, so its 8
    /// corners decide).
    fn hides(&self, eye: [f64; 3], centre: [f64; 3], radius: f64) -> bool {
        if eye[2] <= self.z + SLAB_MARGIN || centre[2] + radius >= self.z - SLAB_MARGIN {
            return false;
        }
        (0..8).all(|k| {
            let c = [0, 1, 2].map(|a| centre[a] + if k >> a & 1 == 1 { radius } else { -radius });
            let t = (self.z - eye[2]) / (c[2] - eye[2]);
            let (x, y) = (eye[0] + t * (c[0] - eye[0]), eye[1] + t * (c[1] - eye[1]));
            (self.x[0]..=self.x[1]).contains(&x) && (self.y[0]..=self.y[1]).contains(&y)
        })
    }
}

/// Drops from the scene every model geom that the top face of an opaque slab
/// (the table) hides from the camera: the face is drawn opaque in front of
/// every sample such a geom covers, so the frame is identical, and llvmpipe
/// does not rasterize it (the lab frame's four feet under the table are
/// cylinders of 2688 triangles each, most of the in-hand camera's work).
/// Returns how many geoms were left out.
pub(super) fn cull_under_slabs(scn: &mut ffi::mjvScene) -> usize {
    let faces: Vec<TopFace> = scene_geoms(scn).iter().filter_map(TopFace::of).collect();
    if faces.is_empty() {
        return 0;
    }
    // Both eyes (they coincide without stereo).
    let eyes = scn.camera.map(|c| c.pos.map(f64::from));
    drop_model_geoms(scn, |g| {
        let (centre, radius) = (g.pos.map(f64::from), g.modelrbound as f64);
        faces
            .iter()
            .any(|f| eyes.iter().all(|e| f.hides(*e, centre, radius)))
    })
}

/// The OpenGL 1.x calls for recording display lists, from EGL.
struct Gl {
    gen_lists: unsafe extern "C" fn(range: i32) -> u32,
    delete_lists: unsafe extern "C" fn(list: u32, range: i32),
    new_list: unsafe extern "C" fn(list: u32, mode: u32),
    end_list: unsafe extern "C" fn(),
    call_list: unsafe extern "C" fn(list: u32),
    begin: unsafe extern "C" fn(mode: u32),
    end: unsafe extern "C" fn(),
    normal3d: unsafe extern "C" fn(x: f64, y: f64, z: f64),
    vertex3d: unsafe extern "C" fn(x: f64, y: f64, z: f64),
}

const GL_COMPILE: u32 = 0x1300;
const GL_QUADS: u32 = 0x0007;

static GL: std::sync::OnceLock<Option<Gl>> = std::sync::OnceLock::new();

fn gl() -> Option<&'static Gl> {
    GL.get_or_init(|| {
        // SAFETY: looking up GL entry points by name; each is checked for
        // null and has the signature of the OpenGL 1.x specification.
        unsafe {
            macro_rules! load {
                ($name:literal, $ty:ty) => {{
                    let p = eglGetProcAddress($name.as_ptr());
                    if p.is_null() {
                        return None;
                    }
                    std::mem::transmute::<*mut c_void, $ty>(p)
                }};
            }
            Some(Gl {
                gen_lists: load!(c"glGenLists", unsafe extern "C" fn(i32) -> u32),
                delete_lists: load!(c"glDeleteLists", unsafe extern "C" fn(u32, i32)),
                new_list: load!(c"glNewList", unsafe extern "C" fn(u32, u32)),
                end_list: load!(c"glEndList", unsafe extern "C" fn()),
                call_list: load!(c"glCallList", unsafe extern "C" fn(u32)),
                begin: load!(c"glBegin", unsafe extern "C" fn(u32)),
                end: load!(c"glEnd", unsafe extern "C" fn()),
                normal3d: load!(c"glNormal3d", unsafe extern "C" fn(f64, f64, f64)),
                vertex3d: load!(c"glVertex3d", unsafe extern "C" fn(f64, f64, f64)),
            })
        }
    })
    .as_ref()
}

/// The grid lines of an infinite plane dimension without a material in
/// MuJoCo 2.2 (its `makePlane`): mjMAXPLANEGRID cells spanning 2.1 · zfar
/// and a little more around the plane's origin (about 21 m per cell in our
/// scenes), the same numbers MuJoCo's own display list uses.
fn infinite_grid_lines(zfar: f64) -> Vec<f64> {
    let n = ffi::mjMAXPLANEGRID as usize;
    let sx = 2.1 * zfar / (n - 2) as f64;
    let d = (2.1 * zfar + 2.0 * sx) / n as f64;
    (0..=n).map(|x| d * x as f64 - d * (n / 2) as f64).collect()
}

/// Cells of a plane's grid to draw: (column, first row, last row).
type Cells = Vec<(u16, u16, u16)>;

/// Per camera, a copy of MuJoCo's plane display lists in which every
/// infinite, untextured plane keeps only the grid cells its view volume can
/// reach, in MuJoCo's order, with MuJoCo's vertices; the other lists call
/// MuJoCo's own. A cell outside the view covers no pixel, so frames are
/// identical, and llvmpipe no longer shades and clips 160 000 grid
/// vertices per frame. `mjr_render` is pointed at a camera's copy for its
/// frame.
pub(super) struct PlaneLists {
    /// Ordinals among the model's planes (`mjvGeom::dataid`) of the
    /// infinite, untextured ones: MuJoCo draws each as one display list of
    /// mjMAXPLANEGRID² quads, most of them far outside any view.
    planes: Vec<usize>,
    /// Their grid lines (the same for all of them).
    lines: Vec<f64>,
    /// MuJoCo's lists (`basePlane`, `rangePlane` entries).
    base: u32,
    range: usize,
    /// Per camera id: our lists' base and the cells each plane's list holds.
    cameras: Vec<Option<(u32, Vec<Option<Cells>>)>>,
}

impl PlaneLists {
    /// After `mjr_makeContext` for `m` (the model the context was made for).
    ///
    /// # Safety
    /// `m` must be valid and `con` made from it, with its GL context current.
    pub(super) unsafe fn new(m: *const ffi::mjModel, con: &ffi::mjrContext) -> PlaneLists {
        let m = &*m;
        let ngeom = m.ngeom.max(0) as usize;
        let types = std::slice::from_raw_parts(m.geom_type, ngeom);
        let matids = std::slice::from_raw_parts(m.geom_matid, ngeom);
        let sizes = std::slice::from_raw_parts(m.geom_size, 3 * ngeom);
        let planes = (0..ngeom)
            .filter(|&i| types[i] == ffi::mjtGeom__mjGEOM_PLANE as i32)
            .enumerate()
            .filter(|&(_, i)| matids[i] < 0 && sizes[3 * i] <= 0.0 && sizes[3 * i + 1] <= 0.0)
            .map(|(ordinal, _)| ordinal)
            .collect();
        PlaneLists {
            planes,
            lines: infinite_grid_lines(m.vis.map.zfar as f64 * m.stat.extent),
            base: con.basePlane,
            range: con.rangePlane.max(0) as usize,
            cameras: Vec::new(),
        }
    }

    /// Points `con` at camera `camera`'s lists, updated for the scene's
    /// current view; [`PlaneLists::restore`] points it back. Does nothing
    /// when the scene has no such plane or GL calls are not available.
    ///
    /// # Safety
    /// The context `con` was made in must be current.
    pub(super) unsafe fn select(
        &mut self,
        camera: usize,
        scn: &ffi::mjvScene,
        view: &Frustum,
        con: &mut ffi::mjrContext,
    ) {
        let Some(gl) = gl().filter(|_| !self.planes.is_empty() && self.range > 0) else {
            return;
        };
        if self.cameras.len() <= camera {
            self.cameras.resize_with(camera + 1, || None);
        }
        let (base, recorded) = match &mut self.cameras[camera] {
            Some(c) => c,
            slot => {
                let ours = (gl.gen_lists)(self.range as i32);
                if ours == 0 {
                    return;
                }
                // Lists we do not change call MuJoCo's.
                for k in 0..self.range as u32 {
                    (gl.new_list)(ours + k, GL_COMPILE);
                    (gl.call_list)(self.base + k);
                    (gl.end_list)();
                }
                slot.insert((ours, vec![None; self.planes.len()]))
            }
        };
        let n = scn.ngeom.max(0) as usize;
        let geoms: &[ffi::mjvGeom] = if n == 0 || scn.geoms.is_null() {
            &[]
        } else {
            std::slice::from_raw_parts(scn.geoms, n)
        };
        let l = &self.lines;
        for (&ordinal, cells_now) in self.planes.iter().zip(recorded.iter_mut()) {
            let Some(g) = geoms.iter().find(|g| {
                g.type_ == ffi::mjtGeom__mjGEOM_PLANE as i32 && g.dataid == ordinal as i32
            }) else {
                continue;
            };
            let cells = visible_cells(l, g, view);
            if cells_now.as_ref() != Some(&cells) {
                // The same calls as MuJoCo's list, for these cells only.
                (gl.new_list)(*base + ordinal as u32 + 1, GL_COMPILE);
                (gl.begin)(GL_QUADS);
                (gl.normal3d)(0.0, 0.0, 1.0);
                for &(x, y0, y1) in &cells {
                    let x = x as usize;
                    for y in y0 as usize..=y1 as usize {
                        (gl.vertex3d)(l[x], l[y], 0.0);
                        (gl.vertex3d)(l[x + 1], l[y], 0.0);
                        (gl.vertex3d)(l[x + 1], l[y + 1], 0.0);
                        (gl.vertex3d)(l[x], l[y + 1], 0.0);
                    }
                }
                (gl.end)();
                (gl.end_list)();
                *cells_now = Some(cells);
            }
        }
        con.basePlane = *base;
    }

    /// Points `con` back at MuJoCo's own plane lists.
    pub(super) fn restore(&self, con: &mut ffi::mjrContext) {
        con.basePlane = self.base;
    }

    /// Deletes our lists (before the GL context goes).
    ///
    /// # Safety
    /// The context the lists were made in must be current.
    pub(super) unsafe fn free(&mut self) {
        if let Some(gl) = gl() {
            for (base, _) in self.cameras.drain(..).flatten() {
                (gl.delete_lists)(base, self.range as i32);
            }
        }
    }
}

/// The cells of a plane grid (lines `l` in the plane's frame, x-major as
/// MuJoCo draws them) that meet the view volume: the grid square is clipped
/// by the view's half-spaces (a convex polygon in the plane), and each
/// column keeps the rows between the polygon's lowest and highest point in
/// that column.
fn visible_cells(l: &[f64], g: &ffi::mjvGeom, view: &Frustum) -> Cells {
    let (lo, hi) = (l[0], l[l.len() - 1]);
    let mut poly = vec![[lo, lo], [hi, lo], [hi, hi], [lo, hi]];
    // n · (P − eye) with P = pos + R (x, y, 0): a x + b y + c.
    let m = g.mat.map(|v| v as f64);
    let rel = [0, 1, 2].map(|k| g.pos[k] as f64 - view.eye[k] as f64);
    for n in view.half_spaces() {
        let a = m[0] * n[0] + m[3] * n[1] + m[6] * n[2];
        let b = m[1] * n[0] + m[4] * n[1] + m[7] * n[2];
        let c = rel[0] * n[0] + rel[1] * n[1] + rel[2] * n[2];
        poly = clip(&poly, a, b, c);
    }
    let mut cells = Cells::new();
    if poly.is_empty() {
        return cells;
    }
    for x in 0..l.len() - 1 {
        let strip = clip(&clip(&poly, -1.0, 0.0, l[x]), 1.0, 0.0, -l[x + 1]);
        if strip.is_empty() {
            continue;
        }
        let ymin = strip.iter().map(|p| p[1]).fold(f64::INFINITY, f64::min);
        let ymax = strip.iter().map(|p| p[1]).fold(f64::NEG_INFINITY, f64::max);
        let first = (0..l.len() - 1).find(|&y| l[y + 1] >= ymin);
        let last = (0..l.len() - 1).rev().find(|&y| l[y] <= ymax);
        if let (Some(y0), Some(y1)) = (first, last) {
            if y0 <= y1 {
                cells.push((x as u16, y0 as u16, y1 as u16));
            }
        }
    }
    cells
}

/// Sutherland–Hodgman: the part of convex polygon `poly` where
/// a x + b y + c ≤ 0.
fn clip(poly: &[[f64; 2]], a: f64, b: f64, c: f64) -> Vec<[f64; 2]> {
    let f = |p: &[f64; 2]| a * p[0] + b * p[1] + c;
    let mut out = Vec::with_capacity(poly.len() + 1);
    for i in 0..poly.len() {
        let (p, q) = (poly[i], poly[(i + 1) % poly.len()]);
        let (fp, fq) = (f(&p), f(&q));
        if fp <= 0.0 {
            out.push(p);
        }
        if (fp <= 0.0) != (fq <= 0.0) {
            let t = fp / (fp - fq);
            out.push([p[0] + t * (q[0] - p[0]), p[1] + t * (q[1] - p[1])]);
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::{clip, ffi, infinite_grid_lines, visible_cells, Frustum, TopFace};

    fn camera(pos: [f32; 3], forward: [f32; 3], up: [f32; 3]) -> Frustum {
        let near = 0.01f32;
        let top = near * (22.5f32).to_radians().tan();
        let c = ffi::mjvGLCamera {
            pos,
            forward,
            up,
            frustum_center: 0.0,
            frustum_bottom: -top,
            frustum_top: top,
            frustum_near: near,
            frustum_far: 50.0,
        };
        Frustum::of(&c, 1.0).unwrap()
    }

    /// A ground plane at the origin with MuJoCo's grid of 200 × 200 cells of
    /// 21 m (zfar 1000 × extent 2).
    fn ground() -> (Vec<f64>, ffi::mjvGeom) {
        let lines = infinite_grid_lines(2000.0);
        assert_eq!((lines.len(), lines[100]), (201, 0.0));
        // SAFETY: mjvGeom is plain old data; all-zero is a valid value.
        let mut g: ffi::mjvGeom = unsafe { std::mem::zeroed() };
        g.type_ = ffi::mjtGeom__mjGEOM_PLANE as i32;
        g.mat = [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0];
        (lines, g)
    }

    #[test]
    fn a_camera_looking_down_keeps_the_cells_under_it() {
        let (lines, g) = ground();
        let view = camera([0.5, 0.5, 1.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]);
        assert_eq!(visible_cells(&lines, &g, &view), vec![(100, 100, 100)]);
        // Over a grid line: both columns.
        let view = camera([0.0, 0.5, 1.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]);
        assert_eq!(
            visible_cells(&lines, &g, &view),
            vec![(99, 100, 100), (100, 100, 100)]
        );
    }

    #[test]
    fn a_camera_looking_at_the_horizon_keeps_a_wedge_and_nothing_behind_it() {
        let (lines, g) = ground();
        let view = camera([0.5, 0.5, 1.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]);
        let cells = visible_cells(&lines, &g, &view);
        let n: usize = cells.iter().map(|c| (c.2 - c.1 + 1) as usize).sum();
        assert!(n > 100 && n < 200 * 200 / 4, "{n} cells");
        // Looking along +y from y = 0.5: no row behind the camera's cell.
        assert!(cells.iter().all(|c| c.1 >= 100), "{cells:?}");
        // Looking up: no cell.
        let view = camera([0.5, 0.5, 1.0], [0.0, 0.0, 1.0], [0.0, 1.0, 0.0]);
        assert!(visible_cells(&lines, &g, &view).is_empty());
    }

    #[test]
    fn clipping_keeps_the_inside_of_a_half_plane() {
        let square = [[0.0, 0.0], [2.0, 0.0], [2.0, 2.0], [0.0, 2.0]];
        // x ≤ 1
        let half = clip(&square, 1.0, 0.0, -1.0);
        let xmax = half.iter().map(|p| p[0]).fold(f64::MIN, f64::max);
        assert_eq!(xmax, 1.0);
        assert_eq!(half.len(), 4);
        // x ≤ −1: nothing
        assert!(clip(&square, 1.0, 0.0, 1.0).is_empty());
        // x + y ≤ 1: a triangle
        assert_eq!(clip(&square, 1.0, 1.0, -1.0).len(), 3);
    }

    fn table() -> ffi::mjvGeom {
        // SAFETY: mjvGeom is plain old data; all-zero is a valid value.
        let mut g: ffi::mjvGeom = unsafe { std::mem::zeroed() };
        g.objtype = ffi::mjtObj__mjOBJ_GEOM as i32;
        g.type_ = ffi::mjtGeom__mjGEOM_BOX as i32;
        g.category = ffi::mjtCatBit__mjCAT_STATIC as i32;
        g.rgba = [0.8, 0.655, 0.45, 1.0];
        g.mat = [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0];
        g.pos = [0.5, 0.0, -0.02];
        g.size = [0.5, 0.8, 0.02];
        g
    }

    #[test]
    fn a_table_top_hides_what_is_under_it_from_above_only() {
        let top = TopFace::of(&table()).unwrap();
        assert_eq!(top.z, 0.0);
        let eye = [0.5, 0.0, 1.0];
        // A foot under the middle of the table.
        assert!(top.hides(eye, [0.5, 0.0, -0.5], 0.05));
        // Touching the top face, or poking through it: not hidden.
        assert!(!top.hides(eye, [0.5, 0.0, -0.05], 0.05));
        // Under the table but seen past its edge from a low, far eye.
        assert!(!top.hides([3.0, 0.0, 0.05], [0.95, 0.0, -0.5], 0.05));
        // Beside the table.
        assert!(!top.hides(eye, [1.2, 0.0, -0.5], 0.05));
        // From below the table top nothing is hidden.
        assert!(!top.hides([0.5, 0.0, -0.1], [0.5, 0.0, -0.5], 0.05));
    }

    #[test]
    fn only_opaque_static_axis_aligned_boxes_are_slabs() {
        assert!(TopFace::of(&table()).is_some());
        let mut g = table();
        g.rgba[3] = 0.5;
        assert!(TopFace::of(&g).is_none(), "translucent");
        let mut g = table();
        g.category = ffi::mjtCatBit__mjCAT_DYNAMIC as i32;
        assert!(TopFace::of(&g).is_none(), "moving");
        let mut g = table();
        g.mat = [0.0, -1.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0];
        assert!(TopFace::of(&g).is_none(), "turned");
        let mut g = table();
        g.type_ = ffi::mjtGeom__mjGEOM_CYLINDER as i32;
        assert!(TopFace::of(&g).is_none(), "not a box");
    }
}
