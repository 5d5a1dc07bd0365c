use super::*;

const TWO_BOXES: &str = r#"
<mujoco>
  <option timestep="0.001"/>
  <worldbody>
    <geom name="floor" type="plane" size="1 1 0.1"/>
    <body name="box" pos="0 0 0.05">
      <freejoint name="box_joint"/>
      <geom name="box:geom" type="box" size="0.05 0.05 0.05" mass="0.1"/>
    </body>
    <body name="far" pos="0.5 0 0.5">
      <freejoint/>
      <geom name="far:geom" type="sphere" size="0.02"/>
    </body>
  </worldbody>
</mujoco>"#;

#[test]
fn malformed_mjcf_returns_mujocos_message() {
    let err = Model::from_xml("<mujoco><worldbody><body></mujoco>", &[])
        .err()
        .unwrap();
    let msg = err.to_string();
    assert!(
        msg.starts_with("MuJoCo could not compile the model"),
        "{msg}"
    );
    assert!(
        msg.to_lowercase().contains("xml"),
        "MuJoCo's own text expected: {msg}"
    );

    let err = Model::from_xml(
        r#"<mujoco><worldbody><geom type="box" size="-1 1 1" name="g"/><geom type="nonsense"/></worldbody></mujoco>"#,
        &[],
    )
    .err()
    .unwrap();
    assert!(
        err.to_string().contains("nonsense") || err.to_string().contains("type"),
        "{err}"
    );
}

#[test]
fn includes_resolve_through_the_vfs() {
    let main = r#"<mujoco><include file="part.xml"/></mujoco>"#;
    let part = r#"<mujoco><worldbody><body name="b"><geom name="g" size="0.1"/></body></worldbody></mujoco>"#;
    let m = Model::from_xml(main, &[("part.xml", part)]).unwrap();
    assert!(m.id(ObjKind::Body, "b").is_ok());
    let missing = Model::from_xml(main, &[]).err().unwrap();
    assert!(missing.to_string().contains("part.xml"), "{missing}");
}

#[test]
fn unknown_names_are_errors_not_panics() {
    let m = Model::from_xml(TWO_BOXES, &[]).unwrap();
    let e = m.id(ObjKind::Geom, "no_such_geom").unwrap_err();
    assert_eq!(e.to_string(), "no geom named `no_such_geom` in the model");
    assert!(m.joint_qpos_addr("nope").is_err());
    assert!(m.id(ObjKind::Body, "bad\0name").is_err());
}

#[test]
fn contacts_between_named_geoms_are_reported() {
    let m = Arc::new(Model::from_xml(TWO_BOXES, &[]).unwrap());
    let floor = m.id(ObjKind::Geom, "floor").unwrap();
    let bx = m.id(ObjKind::Geom, "box:geom").unwrap();
    let far = m.id(ObjKind::Geom, "far:geom").unwrap();
    let mut d = Data::new(m.clone()).unwrap();
    d.forward().unwrap();
    assert!(d.has_contact(floor, bx));
    assert!(d.has_contact(bx, floor));
    assert!(!d.has_contact(floor, far));
    for _ in 0..100 {
        d.step().unwrap();
    }
    // The free sphere falls 0.5 m in 0.1 s? no: only ~5 cm; it is still airborne.
    assert!(!d.has_contact(floor, far));
    assert!(d.has_contact(floor, bx));
    assert!((d.time() - 0.1).abs() < 1e-9);
    // The box rests on the floor: its z stays near 0.05.
    let adr = m.joint_qpos_addr("box_joint").unwrap();
    assert!(
        (d.qpos()[adr + 2] - 0.05).abs() < 2e-3,
        "{}",
        d.qpos()[adr + 2]
    );
}

#[test]
fn data_is_send_and_steps_on_other_threads() {
    let m = Arc::new(Model::from_xml(TWO_BOXES, &[]).unwrap());
    let handles: Vec<_> = (0..2)
        .map(|_| {
            let mut d = Data::new(m.clone()).unwrap();
            std::thread::spawn(move || {
                for _ in 0..50 {
                    d.step().unwrap();
                }
                d.qpos().to_vec()
            })
        })
        .collect();
    let r: Vec<_> = handles.into_iter().map(|h| h.join().unwrap()).collect();
    assert_eq!(
        r[0], r[1],
        "same model and start must give identical states"
    );
}

#[test]
fn runtime_errors_become_err_not_exit() {
    // A model whose stack is too small for the constraint solver makes MuJoCo
    // call mju_error ("mj_stackAlloc: insufficient memory") inside mj_step.
    let xml = r#"<mujoco><size nstack="50"/><worldbody>
      <geom name="floor" type="plane" size="1 1 0.1"/>
      <body pos="0 0 0.05"><freejoint/><geom type="box" size="0.05 0.05 0.05"/></body>
      </worldbody></mujoco>"#;
    match Model::from_xml(xml, &[]) {
        Err(e) => assert!(matches!(e, MjError::Compile(_)), "{e}"),
        Ok(m) => {
            let m = Arc::new(m);
            let r = Data::new(m.clone()).and_then(|mut d| {
                for _ in 0..10 {
                    d.step()?;
                }
                Ok(())
            });
            let e = r.expect_err("a 50-slot stack cannot hold a contact solve");
            assert!(e.to_string().contains("MuJoCo runtime error"), "{e}");
        }
    }
}

#[test]
fn version_is_2_2_2() {
    assert_eq!(version(), "2.2.2");
}
