//! The committed suite files (`assets/robustness/`), each with the sha256
//! this build expects: a new suite is a new file and a new row here.

use d3il_protocol::{ObsType, TaskId};

const ALIGNING_V1: &[u8] = include_bytes!("../../../assets/robustness/aligning-v1.json");
pub const ALIGNING_V1_SHA256: &str =
    "75e2dcd985e67adf8516cc171e23ae9377b28271798905e11f660a3bdb0da246";
const PUSHING_V1: &[u8] = include_bytes!("../../../assets/robustness/pushing-v1.json");
pub const PUSHING_V1_SHA256: &str =
    "25899d09f088d638302084e768b9366bf56626a43f58031f02c9d33ce7c462a1";

const ALIGNING_V2: &[u8] = include_bytes!("../../../assets/robustness/aligning-v2.json");
pub const ALIGNING_V2_SHA256: &str =
    "aa74f7e8ced1d8d0932b57368489fd1951c8617cb1dbed8ab820e42a6d5017e1";
const PUSHING_V2: &[u8] = include_bytes!("../../../assets/robustness/pushing-v2.json");
pub const PUSHING_V2_SHA256: &str =
    "581dd17af6538df6f45bb16238b0a787cac0fd1f7c44d150781bdbd273c851cb";

const ALIGNING_IMAGE_V1: &[u8] =
    include_bytes!("../../../assets/robustness/aligning-image-v1.json");
pub const ALIGNING_IMAGE_V1_SHA256: &str =
    "1057e52c29a889ba95eb4733fd9bd91eea54acacbfa77dfb690ce161ccccc919";

// The six other tasks' first suites (docs/robustness.md, Measured: the
// other tasks).
const AVOIDING_V1: &[u8] = include_bytes!("../../../assets/robustness/avoiding-v1.json");
pub const AVOIDING_V1_SHA256: &str =
    "ddbd3c201f3814d37c87aed98913a471897200edc18f750aa54f80589ce49c9e";
const SORTING_2_V1: &[u8] = include_bytes!("../../../assets/robustness/sorting-2-v1.json");
pub const SORTING_2_V1_SHA256: &str =
    "0fa7a4061c333d5dc8a590880b9e1781433be3b66384151557807d813ddbedfb";
const SORTING_4_V1: &[u8] = include_bytes!("../../../assets/robustness/sorting-4-v1.json");
pub const SORTING_4_V1_SHA256: &str =
    "4809f129b2ade01e2bcfa5471fc40548f52ea513eb2a0b7f881b6712c3d4cf73";
const SORTING_6_V1: &[u8] = include_bytes!("../../../assets/robustness/sorting-6-v1.json");
pub const SORTING_6_V1_SHA256: &str =
    "84bb6f21295803670bab37acdad380dc11cec6ce1c484015ce9fbfd8178f4187";
const STACKING_V1: &[u8] = include_bytes!("../../../assets/robustness/stacking-v1.json");
pub const STACKING_V1_SHA256: &str =
    "3375e506bb82483372920291f61607c1ff5ad10bf2aa466d0d2b837494bc1be9";
const INSERTING_V1: &[u8] = include_bytes!("../../../assets/robustness/inserting-v1.json");
pub const INSERTING_V1_SHA256: &str =
    "eb9ecdd0f7b94c1c0c60040a93161850f4383d43cd18049ae73618effdfeff40";

// Stacking v2: v1 with a latency axis of fractional steps, calibrated on
// the scripted expert (docs/robustness.md, "The other six tasks").
const STACKING_V2: &[u8] = include_bytes!("../../../assets/robustness/stacking-v2.json");
pub const STACKING_V2_SHA256: &str =
    "791f8fb4f7d44286588c7289b82d2ecae729851e4f1466fc8010b45eac859a82";

// The image suites of Sorting-4/6 and Stacking: the current state suite's
// start_shift, latency and dynamics levels (Sorting v1, Stacking v2) and
// Aligning's image levels (docs/robustness.md, "Image suites").
const SORTING_4_IMAGE_V1: &[u8] =
    include_bytes!("../../../assets/robustness/sorting-4-image-v1.json");
pub const SORTING_4_IMAGE_V1_SHA256: &str =
    "58f9435e2e20478da98e6dd29fd0dd4bf406a12b8e46f81dfc4a817c7d0ef263";
const SORTING_6_IMAGE_V1: &[u8] =
    include_bytes!("../../../assets/robustness/sorting-6-image-v1.json");
pub const SORTING_6_IMAGE_V1_SHA256: &str =
    "e2ec11f786fec4be6d1cd2a510b88fa7b7bf625e3494844b23932dabd1e10433";
const STACKING_IMAGE_V1: &[u8] =
    include_bytes!("../../../assets/robustness/stacking-image-v1.json");
pub const STACKING_IMAGE_V1_SHA256: &str =
    "79a4327a7cc275c73e8e7efa591d143a0f3a296082c2a81733c4ecb2947bda4c";

/// Every committed suite: (task, observation type, file name, bytes,
/// expected sha256), oldest first: a task's last one of an observation type
/// is its current suite (what `d3il eval --suite robustness` runs), the
/// older ones stay for replays of older results.
pub(super) const SUITES: &[(TaskId, ObsType, &str, &[u8], &str)] = &[
    (
        TaskId::Aligning,
        ObsType::State,
        "aligning-v1.json",
        ALIGNING_V1,
        ALIGNING_V1_SHA256,
    ),
    (
        TaskId::Pushing,
        ObsType::State,
        "pushing-v1.json",
        PUSHING_V1,
        PUSHING_V1_SHA256,
    ),
    (
        TaskId::Aligning,
        ObsType::State,
        "aligning-v2.json",
        ALIGNING_V2,
        ALIGNING_V2_SHA256,
    ),
    (
        TaskId::Pushing,
        ObsType::State,
        "pushing-v2.json",
        PUSHING_V2,
        PUSHING_V2_SHA256,
    ),
    (
        TaskId::Aligning,
        ObsType::Image,
        "aligning-image-v1.json",
        ALIGNING_IMAGE_V1,
        ALIGNING_IMAGE_V1_SHA256,
    ),
    (
        TaskId::Avoiding,
        ObsType::State,
        "avoiding-v1.json",
        AVOIDING_V1,
        AVOIDING_V1_SHA256,
    ),
    (
        TaskId::Sorting2,
        ObsType::State,
        "sorting-2-v1.json",
        SORTING_2_V1,
        SORTING_2_V1_SHA256,
    ),
    (
        TaskId::Sorting4,
        ObsType::State,
        "sorting-4-v1.json",
        SORTING_4_V1,
        SORTING_4_V1_SHA256,
    ),
    (
        TaskId::Sorting6,
        ObsType::State,
        "sorting-6-v1.json",
        SORTING_6_V1,
        SORTING_6_V1_SHA256,
    ),
    (
        TaskId::Stacking,
        ObsType::State,
        "stacking-v1.json",
        STACKING_V1,
        STACKING_V1_SHA256,
    ),
    (
        TaskId::Inserting,
        ObsType::State,
        "inserting-v1.json",
        INSERTING_V1,
        INSERTING_V1_SHA256,
    ),
    (
        TaskId::Sorting4,
        ObsType::Image,
        "sorting-4-image-v1.json",
        SORTING_4_IMAGE_V1,
        SORTING_4_IMAGE_V1_SHA256,
    ),
    (
        TaskId::Sorting6,
        ObsType::Image,
        "sorting-6-image-v1.json",
        SORTING_6_IMAGE_V1,
        SORTING_6_IMAGE_V1_SHA256,
    ),
    (
        TaskId::Stacking,
        ObsType::Image,
        "stacking-image-v1.json",
        STACKING_IMAGE_V1,
        STACKING_IMAGE_V1_SHA256,
    ),
    (
        TaskId::Stacking,
        ObsType::State,
        "stacking-v2.json",
        STACKING_V2,
        STACKING_V2_SHA256,
    ),
];
