//! What one rollout did, kept so that it can be replayed bit for bit
//! (DESIGN.md: "a rollout is reproducible bit for bit from its initial state
//! and the actions the environment received"): the actions exactly as the
//! environment received them, a digest of the physics state after every step
//! (so that a replay names the first step that differs), the paths of the TCP
//! and of the objects seen from above, the final object poses and the scene's
//! landmarks. Videos and pictures are made from this record on demand.
//!
//! Numeric arrays are packed: little-endian bytes, deflated, base64 (standard
//! alphabet, padded). A paper-protocol result stays a few MiB.

use base64::Engine as _;
use serde::{Deserialize, Serialize};
use std::io::{Read, Write};

/// Version of the trace layout; a replay refuses other versions by name.
pub const TRACE_FORMAT: u32 = 1;

/// How a rollout ended.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Ending {
    /// The task ended the episode early because it succeeded.
    TaskSuccess,
    /// The task ended the episode early without success (e.g. a box fell
    /// off the table in a task that stops on it).
    TaskEnded,
    /// The episode ran to the task's step limit.
    TimeLimit,
    /// The simulation became unstable (a MuJoCo warning): a failure; the
    /// record's `failure` says at which step and why.
    SimUnstable,
    /// Dry runs only: stopped after the job's step cap.
    StepCap,
}

impl Ending {
    pub const ALL: [Ending; 5] = [
        Ending::TaskSuccess,
        Ending::TaskEnded,
        Ending::TimeLimit,
        Ending::SimUnstable,
        Ending::StepCap,
    ];

    /// The name serde writes (`task_success`, `time_limit`, ...).
    pub fn name(self) -> &'static str {
        match self {
            Ending::TaskSuccess => "task_success",
            Ending::TaskEnded => "task_ended",
            Ending::TimeLimit => "time_limit",
            Ending::SimUnstable => "sim_unstable",
            Ending::StepCap => "step_cap",
        }
    }

    /// Words for people ("ended by the task: success").
    pub fn describe(self) -> &'static str {
        match self {
            Ending::TaskSuccess => "succeeded (the task ended the episode)",
            Ending::TaskEnded => "ended by the task without success",
            Ending::TimeLimit => "ran to the step limit",
            Ending::SimUnstable => "the simulation became unstable",
            Ending::StepCap => "stopped at the dry run's step cap",
        }
    }

    /// How a rollout ended, from what the engine knows when it retires it.
    pub fn classify(
        unstable: bool,
        done: bool,
        success: bool,
        steps: usize,
        max_steps: usize,
    ) -> Ending {
        if unstable {
            Ending::SimUnstable
        } else if !done {
            Ending::StepCap
        } else if steps >= max_steps {
            Ending::TimeLimit
        } else if success {
            Ending::TaskSuccess
        } else {
            Ending::TaskEnded
        }
    }
}

impl std::fmt::Display for Ending {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

impl std::str::FromStr for Ending {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        Ending::ALL
            .into_iter()
            .find(|e| e.name() == s)
            .ok_or_else(|| {
                let names: Vec<&str> = Ending::ALL.iter().map(|e| e.name()).collect();
                format!("unknown ending `{s}`; one of {}", names.join(", "))
            })
    }
}

/// What a landmark of the scene is, for the top-down pictures.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum LandmarkKind {
    /// The table top's outline.
    Table,
    /// Where an object is to go (a target region, a goal line, a bin).
    Target,
    /// Something to go around.
    Obstacle,
}

/// A fixed feature of the scene seen from above: an axis-aligned box
/// (`half` = half extents) or, with `round`, a circle of radius `half[0]`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Landmark {
    pub kind: LandmarkKind,
    pub label: String,
    pub center: [f64; 2],
    pub half: [f64; 2],
    #[serde(default)]
    pub round: bool,
}

/// The xy path of one object over the episode (packed f32 pairs, one per
/// state: after the reset, then after every step).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ObjectPath {
    pub name: String,
    pub xy: String,
}

/// Everything needed to replay one rollout and to draw it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RolloutTrace {
    /// [`TRACE_FORMAT`].
    pub format: u32,
    /// Values per action row.
    pub act_dim: usize,
    /// Packed f32: the rows the environment received, one per step, in order.
    pub actions: String,
    /// Packed u32: [`state_digest`] of the physics state after each step.
    pub digests: String,
    /// Packed f32 xyz of the TCP, one per state (the reset's first).
    pub tcp: String,
    /// Each object's top-down path.
    pub objects: Vec<ObjectPath>,
    /// Each object's position after the reset.
    pub start_objects: Vec<(String, [f64; 3])>,
    /// Each object's position when the rollout ended (bit for bit).
    pub final_objects: Vec<(String, [f64; 3])>,
    /// Targets, obstacles and the table, for the pictures.
    #[serde(default)]
    pub landmarks: Vec<Landmark>,
}

/// A packed array that does not unpack.
#[derive(Debug, thiserror::Error)]
pub enum PackError {
    #[error("field `{field}` is not base64: {source}")]
    Base64 {
        field: &'static str,
        source: base64::DecodeError,
    },
    #[error("field `{field}` is not a deflate stream: {source}")]
    Deflate {
        field: &'static str,
        source: std::io::Error,
    },
    #[error("field `{field}` holds {bytes} bytes, not a whole number of {width}-byte values")]
    Length {
        field: &'static str,
        bytes: usize,
        width: usize,
    },
    #[error("field `{field}` holds {values} values, not a whole number of rows of {row}")]
    Rows {
        field: &'static str,
        values: usize,
        row: usize,
    },
    #[error("this trace has format {found}; this build reads format {TRACE_FORMAT}")]
    Format { found: u32 },
}

/// Unpacked arrays are capped so that a hostile record cannot ask for
/// gigabytes: 64 MiB of values.
const MAX_UNPACKED: u64 = 64 << 20;

fn pack_bytes(bytes: &[u8]) -> String {
    let mut enc = flate2::write::DeflateEncoder::new(Vec::new(), flate2::Compression::best());
    enc.write_all(bytes).expect("writing to a Vec");
    let deflated = enc.finish().expect("writing to a Vec");
    base64::engine::general_purpose::STANDARD.encode(deflated)
}

fn unpack_bytes(field: &'static str, text: &str, width: usize) -> Result<Vec<u8>, PackError> {
    let deflated = base64::engine::general_purpose::STANDARD
        .decode(text.trim())
        .map_err(|source| PackError::Base64 { field, source })?;
    let mut out = Vec::new();
    flate2::read::DeflateDecoder::new(deflated.as_slice())
        .take(MAX_UNPACKED + 1)
        .read_to_end(&mut out)
        .map_err(|source| PackError::Deflate { field, source })?;
    if out.len() as u64 > MAX_UNPACKED {
        return Err(PackError::Deflate {
            field,
            source: std::io::Error::other("unpacks to more than 64 MiB"),
        });
    }
    if !out.len().is_multiple_of(width) {
        return Err(PackError::Length {
            field,
            bytes: out.len(),
            width,
        });
    }
    Ok(out)
}

/// Packs f32 values bit for bit.
pub fn pack_f32(values: &[f32]) -> String {
    let bytes: Vec<u8> = values.iter().flat_map(|v| v.to_le_bytes()).collect();
    pack_bytes(&bytes)
}

/// Unpacks what [`pack_f32`] packed; `field` names it in errors.
pub fn unpack_f32(field: &'static str, text: &str) -> Result<Vec<f32>, PackError> {
    Ok(unpack_bytes(field, text, 4)?
        .chunks_exact(4)
        .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
        .collect())
}

pub fn pack_u32(values: &[u32]) -> String {
    let bytes: Vec<u8> = values.iter().flat_map(|v| v.to_le_bytes()).collect();
    pack_bytes(&bytes)
}

pub fn unpack_u32(field: &'static str, text: &str) -> Result<Vec<u32>, PackError> {
    Ok(unpack_bytes(field, text, 4)?
        .chunks_exact(4)
        .map(|c| u32::from_le_bytes([c[0], c[1], c[2], c[3]]))
        .collect())
}

/// Splits `values` into rows of `row`, refusing a ragged tail.
fn rows<T: Copy, const N: usize>(
    field: &'static str,
    values: Vec<T>,
) -> Result<Vec<[T; N]>, PackError> {
    if !values.len().is_multiple_of(N) {
        return Err(PackError::Rows {
            field,
            values: values.len(),
            row: N,
        });
    }
    Ok(values
        .chunks_exact(N)
        .map(|c| std::array::from_fn(|i| c[i]))
        .collect())
}

/// A 32-bit digest of a physics state (FNV-1a over the bits of the given
/// f64 values, folded): equal states give equal digests; a replay compares
/// them step by step to name the first step that differs.
pub fn state_digest<'a>(parts: impl IntoIterator<Item = &'a [f64]>) -> u32 {
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    for part in parts {
        for v in part {
            for b in v.to_bits().to_le_bytes() {
                h ^= u64::from(b);
                h = h.wrapping_mul(0x0000_0100_0000_01b3);
            }
        }
    }
    (h ^ (h >> 32)) as u32
}

/// A trace with its arrays unpacked.
#[derive(Debug, Clone, PartialEq)]
pub struct UnpackedTrace {
    pub act_dim: usize,
    /// One row per step.
    pub actions: Vec<Vec<f32>>,
    pub digests: Vec<u32>,
    pub tcp: Vec<[f32; 3]>,
    pub objects: Vec<(String, Vec<[f32; 2]>)>,
}

impl RolloutTrace {
    /// Unpacks every array, checking the format and the shapes.
    pub fn unpack(&self) -> Result<UnpackedTrace, PackError> {
        if self.format != TRACE_FORMAT {
            return Err(PackError::Format { found: self.format });
        }
        let flat = unpack_f32("actions", &self.actions)?;
        if self.act_dim == 0 || !flat.len().is_multiple_of(self.act_dim) {
            return Err(PackError::Rows {
                field: "actions",
                values: flat.len(),
                row: self.act_dim,
            });
        }
        let actions = flat
            .chunks_exact(self.act_dim)
            .map(<[f32]>::to_vec)
            .collect();
        let objects = self
            .objects
            .iter()
            .map(|o| {
                Ok((
                    o.name.clone(),
                    rows("objects.xy", unpack_f32("objects.xy", &o.xy)?)?,
                ))
            })
            .collect::<Result<_, PackError>>()?;
        Ok(UnpackedTrace {
            act_dim: self.act_dim,
            actions,
            digests: unpack_u32("digests", &self.digests)?,
            tcp: rows("tcp", unpack_f32("tcp", &self.tcp)?)?,
            objects,
        })
    }
}

/// Collects a trace while a rollout runs (the engine pushes every step).
#[derive(Debug, Clone, Default)]
pub struct TraceBuilder {
    act_dim: usize,
    actions: Vec<f32>,
    digests: Vec<u32>,
    tcp: Vec<f32>,
    objects: Vec<(String, Vec<f32>)>,
    start_objects: Vec<(String, [f64; 3])>,
    landmarks: Vec<Landmark>,
}

impl TraceBuilder {
    /// Starts a trace at the state after the reset.
    pub fn start(
        act_dim: usize,
        tcp: [f64; 3],
        objects: Vec<(String, [f64; 3])>,
        landmarks: Vec<Landmark>,
    ) -> TraceBuilder {
        let mut t = TraceBuilder {
            act_dim,
            objects: objects
                .iter()
                .map(|(n, _)| (n.clone(), Vec::new()))
                .collect(),
            start_objects: objects.clone(),
            landmarks,
            ..TraceBuilder::default()
        };
        t.push_state(tcp, &objects);
        t
    }

    fn push_state(&mut self, tcp: [f64; 3], objects: &[(String, [f64; 3])]) {
        self.tcp.extend(tcp.iter().map(|&v| v as f32));
        for ((_, path), (_, p)) in self.objects.iter_mut().zip(objects) {
            path.extend([p[0] as f32, p[1] as f32]);
        }
    }

    /// One step: the action the environment received and the state after it.
    pub fn push_step(
        &mut self,
        action: &[f32],
        digest: u32,
        tcp: [f64; 3],
        objects: &[(String, [f64; 3])],
    ) {
        self.actions.extend_from_slice(action);
        self.digests.push(digest);
        self.push_state(tcp, objects);
    }

    /// Steps pushed so far.
    pub fn steps(&self) -> usize {
        self.digests.len()
    }

    /// Packs the trace; `final_objects` are the poses when the rollout ended.
    pub fn finish(self, final_objects: Vec<(String, [f64; 3])>) -> RolloutTrace {
        RolloutTrace {
            format: TRACE_FORMAT,
            act_dim: self.act_dim,
            actions: pack_f32(&self.actions),
            digests: pack_u32(&self.digests),
            tcp: pack_f32(&self.tcp),
            objects: self
                .objects
                .into_iter()
                .map(|(name, xy)| ObjectPath {
                    name,
                    xy: pack_f32(&xy),
                })
                .collect(),
            start_objects: self.start_objects,
            final_objects,
            landmarks: self.landmarks,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn packed_floats_come_back_bit_for_bit() {
        let v = vec![0.1f32, -0.0, f32::MIN_POSITIVE, 1.0e-42, 3.4e38, -7.25];
        let back = unpack_f32("actions", &pack_f32(&v)).unwrap();
        let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
        assert_eq!(bits(&back), bits(&v));
        assert_eq!(
            unpack_u32("d", &pack_u32(&[1, u32::MAX, 7])).unwrap(),
            vec![1, u32::MAX, 7]
        );
    }

    #[test]
    fn bad_packing_is_named() {
        let e = unpack_f32("actions", "not base64!").unwrap_err();
        assert!(e.to_string().contains("`actions` is not base64"), "{e}");
        let e = unpack_f32("actions", &pack_bytes(&[1, 2, 3])).unwrap_err();
        assert!(e.to_string().contains("3 bytes"), "{e}");
        let trace = TraceBuilder::start(2, [0.0; 3], vec![], vec![]).finish(vec![]);
        let e = RolloutTrace { format: 9, ..trace }.unpack().unwrap_err();
        assert!(e.to_string().contains("format 9"), "{e}");
    }

    #[test]
    fn a_trace_unpacks_to_what_was_pushed() {
        let objects = |x: f64| vec![("box".to_string(), [x, 2.0 * x, 0.5])];
        let mut b = TraceBuilder::start(2, [0.5, 0.1, 0.2], objects(0.0), vec![]);
        b.push_step(&[0.25, -0.5], 7, [0.6, 0.1, 0.2], &objects(1.0));
        b.push_step(&[0.75, 0.5], 9, [0.7, 0.1, 0.2], &objects(2.0));
        assert_eq!(b.steps(), 2);
        let t = b.finish(objects(2.0)).unpack().unwrap();
        assert_eq!(t.actions, vec![vec![0.25, -0.5], vec![0.75, 0.5]]);
        assert_eq!(t.digests, vec![7, 9]);
        assert_eq!(t.tcp.len(), 3);
        assert_eq!(t.objects[0].1, vec![[0.0, 0.0], [1.0, 2.0], [2.0, 4.0]]);
    }

    #[test]
    fn digests_see_one_ulp() {
        let a = [0.1f64, 0.2];
        let b = [0.1f64, f64::from_bits(0.2f64.to_bits() + 1)];
        assert_ne!(state_digest([&a[..]]), state_digest([&b[..]]));
        assert_eq!(state_digest([&a[..]]), state_digest([&a[..]]));
    }

    #[test]
    fn endings_parse_by_their_serde_names() {
        for e in Ending::ALL {
            let json = serde_json::to_string(&e).unwrap();
            assert_eq!(json, format!("\"{}\"", e.name()));
            assert_eq!(e.name().parse::<Ending>().unwrap(), e);
        }
        assert!("crashed"
            .parse::<Ending>()
            .unwrap_err()
            .contains("time_limit"));
    }
}
