//! (d) The known deviations from the original, in one list, each with what
//! it can change in a reported number. The one place they are listed for
//! readers of results (README "Fidelity notes" and docs/fidelity.md point
//! here); the documents named in `source` give the details.

use d3il_protocol::fidelity::Deviation;

const KNOWN: &[(&str, &str, &str)] = &[
    (
        "MuJoCo 2.2.2 here, 2.3.2 in the original",
        "docs/original-d3il.md §01.7.15, §10.7.3",
        "None measured for these models: the original's closed-loop actions replayed here follow its TCP to about 1e-12 m for whole episodes (section 2). Resting heights may differ by up to ~0.1 mm, which could move a success threshold only for an object ending within that distance of it.",
    ),
    (
        "Robot collision geometry: primitive shapes (capsules, boxes) instead of the Panda's meshes",
        "docs/mjcf.md \"Deviations from the original\"",
        "Only rollouts in which a link or the hand (not the rod or the finger tips) touches an object or the table can end differently; every primitive lies inside the mesh's bounds. No such contact occurs in the recorded episodes.",
    ),
    (
        "Contact buffers nconmax = njmax = 500 instead of 2000",
        "docs/mjcf.md \"Buffer sizes\"",
        "None while no buffer overflows; an overflow stops the rollout with an error instead of a truncated contact list, so it cannot change a number silently.",
    ),
    (
        "Policies run in tract (float32) here, in onnxruntime there",
        "reference-closed-loop README; section 2",
        "The same network gives outputs a float32 rounding apart, which a closed loop amplifies: outcomes near a decision boundary flip state by state (align_bc: the same outcome on about 47 of 60 initial states), while success rates agree within their 95 % intervals.",
    ),
    (
        "Policy noise comes from the evaluator's seeded generator, not numpy's",
        "docs/submission.md; reference-closed-loop README",
        "Stochastic policies can be compared with the original only in distribution (rates and intervals), not rollout by rollout.",
    ),
    (
        "Contact-rich motion is chaotic",
        "docs/original-d3il.md §01.7.10; section 1",
        "Not a deviation but a limit of any comparison: a one-ulp change of the initial state ends the agreement of a pushing phase within tens of steps, so single contact trajectories are compared loosely and numbers as distributions over initial states.",
    ),
    (
        "Image scenes draw the Panda's visual meshes from example-robot-data, links and hand reduced to 1,000 triangles",
        "docs/images.md \"How close our pixels are to the original's\"",
        "Front-camera pixels differ from the original's by about 1/255 on average, all of it on the robot's pixels (section 3), mostly from the reduction (0.36-0.40/255 with the full meshes); in-hand frames agree to under 0.1/255. What this does to an image policy's success rate has not been measured.",
    ),
    (
        "4x multisampling (llvmpipe's maximum) instead of 16x on the original's GPU",
        "docs/images.md \"Rendering\"",
        "Edges a little less smooth; the original's own frames on an H100 differ from its llvmpipe frames by 1.0-1.2/255 (front) and 1.5-3.7/255 (in-hand), more than ours from its llvmpipe frames.",
    ),
    (
        "Robots drawn with primitive shapes on builds without the meshes",
        "docs/images.md; README \"Fidelity notes\"",
        "Front views off by 4-6/255 on average; such image results are badged and ranked apart (robot_look in the manifest), never averaged with meshed ones.",
    ),
    (
        "Image Aligning's low-dimensional input (the previous desired TCP) is an assumption",
        "docs/images.md \"What an image policy gets\"",
        "If the original gave Aligning image policies something else, policies trained on its data see a different low-dimensional input here; unverified, no image-policy reference run exists.",
    ),
    (
        "The OpenGL context is made ahead of time, without the original's extra mj_forward at the first observation",
        "docs/images.md \"Image pipeline\"",
        "None: that call changes no state, only when derived quantities are refreshed.",
    ),
    (
        "Avoiding keeps the environment's 250-step limit, without the reference evaluation's 150-row buffer crash",
        "docs/original-d3il.md §10.6.6, §10.7.2",
        "Slow Avoiding policies that finish between steps 149 and 250 succeed here; if the paper's numbers came from an effective 149-step cap, its Avoiding success rates of such policies are lower than ours.",
    ),
    (
        "Initial states of Avoiding, Sorting and Inserting are our own samples from the original's distributions (Aligning, Pushing, Stacking use the original test contexts)",
        "docs/tasks.md; README \"Fidelity notes\"",
        "Per-state results differ; rates differ from the original's within the sampling error of the state set.",
    ),
    (
        "Inserting was never run in the original",
        "docs/original-d3il.md §01.9",
        "No reference data: Inserting numbers are this implementation's and unverified against the original.",
    ),
];

/// The list, in the report's form.
pub fn known() -> Vec<Deviation> {
    KNOWN
        .iter()
        .map(|(what, source, effect)| Deviation {
            what: (*what).into(),
            source: (*source).into(),
            effect: (*effect).into(),
        })
        .collect()
}
