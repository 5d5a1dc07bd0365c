//! Assembles a task scene as one MJCF string plus in-memory include files
//! (docs/original-d3il.md §01.1.1): base file, primitive objects and camera bodies in the base
//! worldbody, then includes of the table, the task's XML objects and the robot.

use crate::mujoco::{MjError, Model};
use crate::robot::RobotVariant;
use sha2::{Digest, Sha256};
use std::fmt::Write;

const BASE_XML: &str = include_str!("../../../assets/mjcf/base.xml");
const TABLE_XML: &str = include_str!("../../../assets/mjcf/table.xml");
const PANDA_ROD_XML: &str = include_str!("../../../assets/mjcf/panda_rod.xml");
const PANDA_GRIPPER_XML: &str = include_str!("../../../assets/mjcf/panda_gripper.xml");

include!(concat!(env!("OUT_DIR"), "/panda_meshes.rs"));

/// How the robot is drawn ([`RobotLook`], recorded in image results'
/// manifests). Physics is the same either way: the collision geoms stay, and
/// the meshes are visual-only geoms (no contacts) on bodies whose inertia is
/// given explicitly (docs/original-d3il.md §01.2.3).
///
/// [`RobotLook::Meshes`] is the Panda's visual meshes (franka_description,
/// from the `example-robot-data` package, converted by scripts/panda_meshes.py
/// with MuJoCo's own vertex normals and compiled in), drawn like the
/// original's (docs/original-d3il.md §01.2.5, §01.6): each link's `:geom1` is
/// its mesh in white at alpha 0.19, the blend of the original's two drawings
/// of it at alpha 0.1 (its `:geom1` and `:geom2`); the hand's and fingers'
/// `:geom1` are their meshes in MuJoCo's default grey. The primitive collision
/// geoms `:geom2` move to geom group 3, which is not drawn.
pub use d3il_protocol::RobotLook;

/// Whether this build has the meshes (converted before it was compiled).
pub fn meshes_available() -> bool {
    MESH_FILES
        .iter()
        .all(|f| PANDA_MESHES.iter().any(|(name, _)| name == f))
}

/// Meshes when this build has them, else primitives.
pub fn best_look() -> RobotLook {
    if meshes_available() {
        RobotLook::Meshes
    } else {
        RobotLook::Primitives
    }
}

/// The link bodies' geom name stems, link 0 to 7 (links 1-3 are named after
/// their joints, docs/original-d3il.md §01.2.5), drawn with `panda_link<i>.obj`.
const LINK_GEOMS: [&str; 8] = [
    "panda_rb0_link0",
    "panda_rb0_joint1",
    "panda_rb0_joint2",
    "panda_rb0_joint3",
    "panda_rb0_link4",
    "panda_rb0_link5",
    "panda_rb0_link6",
    "panda_rb0_link7",
];

/// Every mesh file the meshed look uses (scripts/panda_meshes.py writes them).
const MESH_FILES: [&str; 10] = [
    "panda_link0.obj",
    "panda_link1.obj",
    "panda_link2.obj",
    "panda_link3.obj",
    "panda_link4.obj",
    "panda_link5.obj",
    "panda_link6.obj",
    "panda_link7.obj",
    "panda_hand.obj",
    "panda_finger.obj",
];

/// Replaces the element that starts with `start` (up to its `/>`) by
/// `f(element)`; None when `start` does not occur exactly once.
fn replace_element(xml: &str, start: &str, f: impl Fn(&str) -> String) -> Option<String> {
    if xml.matches(start).count() != 1 {
        return None;
    }
    let i = xml.find(start)?;
    let end = i + xml[i..].find("/>")? + 2;
    Some(format!("{}{}{}", &xml[..i], f(&xml[i..end]), &xml[end..]))
}

/// The robot MJCF with the visual geoms as meshes (see [`RobotLook::Meshes`]);
/// None if the file does not have the expected geoms.
fn with_meshes(robot_xml: &str) -> Option<String> {
    let hide = |e: &str| format!("{} group=\"3\"/>", e.trim_end_matches("/>").trim_end());
    let mesh = |name: &str, mesh: &str, extra: &str| {
        format!(
            r#"<geom name="{name}" type="mesh" mesh="{mesh}"{extra} contype="0" conaffinity="0""#
        )
    };
    let mut x = robot_xml.to_string();
    for (i, g) in LINK_GEOMS.iter().enumerate() {
        // The original draws the mesh twice in white at alpha 0.1 (its
        // visual and its collision geom), one right after the other in each
        // of MuJoCo's two transparent passes (same position and size, so
        // adjacent in its depth order): two blends at 0.1 are one at
        // 1 - 0.9² = 0.19, drawn once for half the cost (docs/images.md).
        let link = format!("panda_link{i}");
        x = replace_element(&x, &format!(r#"<geom name="{g}:geom1""#), |_| {
            format!(
                "{} group=\"1\"/>",
                mesh(&format!("{g}:geom1"), &link, r#" rgba="1 1 1 0.19""#)
            )
        })?;
    }
    let parts = [
        ("panda_rb0_hand", "panda_hand", ""),
        ("panda_rb0_leftfinger", "panda_finger", ""),
        // The same mesh turned 180° about z (docs/original-d3il.md §01.2.5).
        (
            "panda_rb0_rightfinger",
            "panda_finger",
            r#" quat="0 0 0 1""#,
        ),
    ];
    for (g, m, quat) in parts {
        x = replace_element(&x, &format!(r#"<geom name="{g}:geom1""#), |_| {
            format!("{} group=\"1\"/>", mesh(&format!("{g}:geom1"), m, quat))
        })?;
    }
    for g in LINK_GEOMS.iter().chain(&[
        "panda_rb0_hand",
        "panda_rb0_leftfinger",
        "panda_rb0_rightfinger",
    ]) {
        x = replace_element(&x, &format!(r#"<geom name="{g}:geom2""#), hide)?;
    }
    let asset: String = MESH_FILES
        .iter()
        .map(|f| {
            format!(
                r#"<mesh name="{}" file="{f}"/>"#,
                f.trim_end_matches(".obj")
            )
        })
        .collect();
    let body = x.find("<worldbody>")?;
    x.insert_str(body, &format!("<asset>{asset}</asset>\n  "));
    Some(x)
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Shape {
    Box,
    Cylinder,
    Sphere,
}

/// A code-defined object (docs/original-d3il.md §01.1.6).
#[derive(Debug, Clone)]
pub struct Primitive {
    pub name: String,
    pub shape: Shape,
    pub pos: [f64; 3],
    /// (w, x, y, z)
    pub quat: [f64; 4],
    pub size: Vec<f64>,
    /// Set only when non-zero; MuJoCo computes the inertia for the shape.
    pub mass: f64,
    pub rgba: [f64; 4],
    pub is_static: bool,
    pub visual_only: bool,
    pub solref: Option<[f64; 2]>,
    pub solimp: Option<Vec<f64>>,
    /// Extra geom attributes a task needs (friction, priority, ...), verbatim.
    pub geom_attrs: String,
}

impl Primitive {
    pub fn new(name: &str, shape: Shape, pos: [f64; 3], size: &[f64]) -> Self {
        Primitive {
            name: name.to_string(),
            shape,
            pos,
            quat: [1.0, 0.0, 0.0, 0.0],
            size: size.to_vec(),
            mass: 0.1,
            rgba: [0.5, 0.5, 0.5, 1.0],
            is_static: false,
            visual_only: false,
            solref: None,
            solimp: None,
            geom_attrs: String::new(),
        }
    }
}

fn join(v: &[f64]) -> String {
    v.iter()
        .map(|x| format!("{x}"))
        .collect::<Vec<_>>()
        .join(" ")
}

/// Everything that defines one task's compiled model.
#[derive(Debug, Clone)]
pub struct SceneSpec {
    pub robot: RobotVariant,
    pub primitives: Vec<Primitive>,
    /// Bodies added after the primitives (e.g. the task's `bp_cam`), verbatim MJCF.
    pub extra_bodies: String,
    /// Task XML objects as (file name, `<mujoco>` include contents), in order.
    pub includes: Vec<(String, String)>,
    /// Robot look (rendering only). [`RobotLook::Meshes`] in a build without
    /// the meshes falls back to primitives; check
    /// [`meshes_available`] first.
    pub look: RobotLook,
    /// Mesh files (name, OBJ) that replace the compiled-in ones of the same
    /// name in the meshed look; empty for every evaluation (a test compares
    /// the compiled-in meshes with the full ones, docs/images.md).
    pub meshes: Vec<(String, String)>,
}

/// The bp_cam body every task adds (docs/original-d3il.md §01.6).
pub const BP_CAM: &str = r#"<body name="bp_cam" pos="1.05 0 1.2" quat="0.6830127 0.1830127 0.1830127 0.683012"><camera name="bp_cam" mode="fixed" fovy="45" pos="0 0 0" quat="1 0 0 0"/></body>"#;

impl SceneSpec {
    pub fn new(robot: RobotVariant) -> Self {
        SceneSpec {
            robot,
            primitives: Vec::new(),
            extra_bodies: BP_CAM.to_string(),
            includes: Vec::new(),
            look: RobotLook::Primitives,
            meshes: Vec::new(),
        }
    }

    /// The look this scene draws: [`SceneSpec::look`], except that meshes
    /// in a build without them are primitives.
    pub fn drawn_look(&self) -> RobotLook {
        match self.look {
            RobotLook::Meshes if meshes_available() => RobotLook::Meshes,
            _ => RobotLook::Primitives,
        }
    }

    /// The root MJCF and the include files.
    pub fn assemble(&self) -> (String, Vec<(String, String)>) {
        let mut prims = String::new();
        for p in &self.primitives {
            let _ = write!(
                prims,
                r#"<body name="{}" pos="{}" quat="{}">"#,
                p.name,
                join(&p.pos),
                join(&p.quat)
            );
            let kind = match p.shape {
                Shape::Box => "box",
                Shape::Cylinder => "cylinder",
                Shape::Sphere => "sphere",
            };
            let _ = write!(
                prims,
                r#"<geom name="{}:geom" type="{kind}" size="{}" rgba="{}""#,
                p.name,
                join(&p.size),
                join(&p.rgba)
            );
            if p.mass != 0.0 {
                let _ = write!(prims, r#" mass="{}""#, p.mass);
            }
            if p.visual_only {
                prims.push_str(r#" contype="0" conaffinity="0""#);
            }
            if let Some(s) = p.solref {
                let _ = write!(prims, r#" solref="{}""#, join(&s));
            }
            if let Some(s) = &p.solimp {
                let _ = write!(prims, r#" solimp="{}""#, join(s));
            }
            if !p.geom_attrs.is_empty() {
                let _ = write!(prims, " {}", p.geom_attrs);
            }
            prims.push_str("/>");
            if !p.is_static {
                let _ = write!(prims, r#"<freejoint name="{}:joint"/>"#, p.name);
            }
            prims.push_str("</body>\n");
        }
        let robot_file = match self.robot {
            RobotVariant::Rod => "panda_rod.xml",
            RobotVariant::Gripper => "panda_gripper.xml",
        };
        let mut includes = String::from("<include file=\"table.xml\"/>\n");
        for (name, _) in &self.includes {
            let _ = writeln!(includes, "<include file=\"{name}\"/>");
        }
        let _ = writeln!(includes, "<include file=\"{robot_file}\"/>");
        let main = BASE_XML
            .replace("<!-- D3IL:PRIMITIVES -->", &prims)
            .replace("<!-- D3IL:OBJECTS -->", &self.extra_bodies)
            .replace("<!-- D3IL:INCLUDES -->", &includes);
        let mut files = vec![("table.xml".to_string(), TABLE_XML.to_string())];
        files.extend(self.includes.iter().cloned());
        let robot_xml = match self.robot {
            RobotVariant::Rod => PANDA_ROD_XML,
            RobotVariant::Gripper => PANDA_GRIPPER_XML,
        };
        let meshed = match self.drawn_look() {
            RobotLook::Meshes => with_meshes(robot_xml),
            RobotLook::Primitives => None,
        };
        match meshed {
            Some(xml) => {
                files.push((robot_file.to_string(), xml));
                for f in MESH_FILES {
                    let obj = self
                        .meshes
                        .iter()
                        .map(|(n, o)| (n.as_str(), o.as_str()))
                        .chain(PANDA_MESHES.iter().copied())
                        .find(|(n, _)| *n == f);
                    if let Some((_, obj)) = obj {
                        files.push((f.to_string(), obj.to_string()));
                    }
                }
            }
            None => files.push((robot_file.to_string(), robot_xml.to_string())),
        }
        (main, files)
    }

    /// sha256 over the root MJCF and every include, in order (for manifests).
    pub fn sha256(&self) -> String {
        let (main, files) = self.assemble();
        let mut h = Sha256::new();
        h.update(main.as_bytes());
        for (n, c) in &files {
            h.update(n.as_bytes());
            h.update([0u8]);
            h.update(c.as_bytes());
        }
        hex::encode(h.finalize())
    }

    pub fn compile(&self) -> Result<Model, MjError> {
        let (main, files) = self.assemble();
        let refs: Vec<(&str, &str)> = files
            .iter()
            .map(|(n, c)| (n.as_str(), c.as_str()))
            .collect();
        Model::from_xml(&main, &refs)
    }
}
