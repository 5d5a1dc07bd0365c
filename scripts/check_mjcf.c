/*
 * check_mjcf: verifies our own MJCF (assets/mjcf/) against docs/original-d3il.md §01 with real MuJoCo 2.2.
 *
 * Build and run from the repository root:
 *   gcc -O2 -std=c11 -Wall -Wextra -o /tmp/check_mjcf scripts/check_mjcf.c -lmujoco -lm
 *   /tmp/check_mjcf [assets/mjcf]
 *
 * It assembles the scene the way the Rust scene builder does (base.xml with its
 * D3IL:INCLUDES marker replaced by <include> elements, every file served from a MuJoCo
 * VFS), and also from a temporary directory on disk, for both robot variants. Then it
 * checks the compiled model against the numbers in docs/original-d3il.md §01 and runs short simulations.
 * Exit status 0 only if every check passes.
 */
#define _GNU_SOURCE
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include <mujoco/mujoco.h>

static int g_pass = 0, g_fail = 0;

static void check(int ok, const char* fmt, ...) {
  va_list ap;
  va_start(ap, fmt);
  printf("  [%s] ", ok ? "PASS" : "FAIL");
  vprintf(fmt, ap);
  printf("\n");
  va_end(ap);
  if (ok) g_pass++; else g_fail++;
}

static void die(const char* fmt, ...) {
  va_list ap;
  va_start(ap, fmt);
  fprintf(stderr, "check_mjcf: ");
  vfprintf(stderr, fmt, ap);
  fprintf(stderr, "\n");
  va_end(ap);
  exit(2);
}

static char* read_file(const char* dir, const char* name, long* len_out) {
  char path[4096];
  snprintf(path, sizeof path, "%s/%s", dir, name);
  FILE* f = fopen(path, "rb");
  if (!f) die("cannot open %s (run from the repository root or pass the assets/mjcf directory)", path);
  fseek(f, 0, SEEK_END);
  long n = ftell(f);
  fseek(f, 0, SEEK_SET);
  char* buf = malloc(n + 1);
  if (!buf || fread(buf, 1, n, f) != (size_t)n) die("cannot read %s", path);
  buf[n] = 0;
  fclose(f);
  if (len_out) *len_out = n;
  return buf;
}

static void write_file(const char* dir, const char* name, const char* data) {
  char path[4096];
  snprintf(path, sizeof path, "%s/%s", dir, name);
  FILE* f = fopen(path, "wb");
  if (!f || fputs(data, f) < 0) die("cannot write %s", path);
  fclose(f);
}

/* Replace the first occurrence of `marker` in `src` with `repl` (new malloc'd string). */
static char* replace_marker(const char* src, const char* marker, const char* repl) {
  const char* at = strstr(src, marker);
  if (!at) die("marker %s not found in base.xml", marker);
  size_t pre = at - src, ml = strlen(marker), rl = strlen(repl), rest = strlen(at + ml);
  char* out = malloc(pre + rl + rest + 1);
  memcpy(out, src, pre);
  memcpy(out + pre, repl, rl);
  memcpy(out + pre + rl, at + ml, rest + 1);
  return out;
}

static void vfs_add_mem(mjVFS* vfs, const char* name, const char* data) {
  int n = (int)strlen(data);
  if (mj_makeEmptyFileVFS(vfs, name, n) != 0) die("VFS: cannot add %s", name);
  int i = mj_findFileVFS(vfs, name);
  if (i < 0) die("VFS: %s vanished", name);
  memcpy(vfs->filedata[i], data, n);
}

/* The scene builder's job in miniature: fill the two markers of base.xml (docs/original-d3il.md §01.1.1 order). */
static char* root_xml_with(const char* dir, const char* robot_file, const char* objects) {
  char* base = read_file(dir, "base.xml", NULL);
  char inc[512];
  /* table, task XML objects (none here), robot */
  snprintf(inc, sizeof inc, "<include file=\"table.xml\"/>\n  <include file=\"%s\"/>", robot_file);
  char* with_inc = replace_marker(base, "<!-- D3IL:INCLUDES -->", inc);
  char* root = replace_marker(with_inc, "<!-- D3IL:OBJECTS -->", objects);
  free(base);
  free(with_inc);
  return root;
}

static char* root_xml(const char* dir, const char* robot_file) { return root_xml_with(dir, robot_file, ""); }

/* Load through the VFS only: nothing of the scene is read from disk by MuJoCo. */
static mjModel* load_vfs_with(const char* dir, const char* robot_file, const char* objects) {
  mjVFS* vfs = malloc(sizeof(mjVFS));
  if (!vfs) die("out of memory");
  mj_defaultVFS(vfs);
  char* root = root_xml_with(dir, robot_file, objects);
  char* table = read_file(dir, "table.xml", NULL);
  char* robot = read_file(dir, robot_file, NULL);
  vfs_add_mem(vfs, "scene_root.xml", root);
  vfs_add_mem(vfs, "table.xml", table);
  vfs_add_mem(vfs, robot_file, robot);
  char err[1000] = "";
  mjModel* m = mj_loadXML("scene_root.xml", vfs, err, sizeof err);
  if (!m) printf("  VFS load error: %s\n", err);
  else if (err[0]) printf("  VFS load warning: %s\n", err);
  mj_deleteVFS(vfs);
  free(vfs);
  free(root);
  free(table);
  free(robot);
  return m;
}

static mjModel* load_vfs(const char* dir, const char* robot_file) { return load_vfs_with(dir, robot_file, ""); }

/* Load from a temporary directory on disk (root written there, includes copied beside it). */
static mjModel* load_tmpdir(const char* dir, const char* robot_file) {
  char tmpl[] = "/tmp/check_mjcf.XXXXXX";
  char* tmp = mkdtemp(tmpl);
  if (!tmp) die("mkdtemp failed");
  char* root = root_xml(dir, robot_file);
  char* table = read_file(dir, "table.xml", NULL);
  char* robot = read_file(dir, robot_file, NULL);
  write_file(tmp, "scene_root.xml", root);
  write_file(tmp, "table.xml", table);
  write_file(tmp, robot_file, robot);
  char path[4096], err[1000] = "";
  snprintf(path, sizeof path, "%s/scene_root.xml", tmp);
  mjModel* m = mj_loadXML(path, NULL, err, sizeof err);
  if (!m) printf("  disk load error: %s\n", err);
  const char* names[] = {"scene_root.xml", "table.xml", robot_file};
  for (int i = 0; i < 3; i++) {
    snprintf(path, sizeof path, "%s/%s", tmp, names[i]);
    unlink(path);
  }
  rmdir(tmp);
  free(root);
  free(table);
  free(robot);
  return m;
}

static int id_of(const mjModel* m, int type, const char* name) {
  int id = mj_name2id(m, type, name);
  if (id < 0) check(0, "name %s exists (type %d)", name, type);
  return id;
}

static int near(double a, double b, double tol) { return fabs(a - b) <= tol; }

static int is_finite_vec(const mjtNum* v, int n) {
  for (int i = 0; i < n; i++)
    if (!isfinite(v[i])) return 0;
  return 1;
}

/* docs/original-d3il.md §01.4.5 initial arm poses and the reference TCP after reset (stale xpos). */
typedef struct {
  const char* task;
  double q[7];
  double tcp[3];
} InitPose;

static const InitPose INIT_POSES[] = {
    {"Avoiding/Pushing/Inserting",
     {-0.356408684719, 0.429445454037, -0.135010595301, -2.054651893021, 0.093578222916,
      2.480717940701, 0.232506758849},
     {0.524928466341, -0.279736727592, 0.122359305991}},
    {"Aligning",
     {-0.392758359871, 0.321778123396, -0.212502852524, -1.843581356712, 0.083148880386,
      2.160344058282, 0.144795218197},
     {0.524957808877, -0.348818109410, 0.251597893428}},
    {"Sorting",
     {-0.326826625791, 0.245625661929, -0.203252767156, -1.952193734597, 0.063150520371,
      2.195506134794, 0.224575845050},
     {0.524963266675, -0.299291796196, 0.251606692579}},
    {"Stacking",
     {-1.1708e-08, -0.043618586668, 1.3201e-08, -2.188421166999, -5.947e-09, 2.149904161054,
      0.785398167212},
     {0.524977572414, -1.0e-11, 0.301514222825}},
};

static const double Q_SCENE[7] = {3.57795216e-09, 0.174532920, 3.30500960e-08, -0.872664630,
                                  -1.14096181e-07, 1.22173047, 0.785398126};

static const char* ARM_JOINTS[7] = {"panda_rb0_joint1", "panda_rb0_joint2", "panda_rb0_joint3",
                                    "panda_rb0_joint4", "panda_rb0_joint5", "panda_rb0_joint6",
                                    "panda_rb0_joint7"};
static const char* FINGER_JOINTS[2] = {"panda_rb0_finger_joint1", "panda_rb0_finger_joint2"};

static void set_arm(const mjModel* m, mjData* d, const double q[7], double f1, double f2) {
  mj_resetData(m, d);
  for (int i = 0; i < 7; i++) d->qpos[m->jnt_qposadr[mj_name2id(m, mjOBJ_JOINT, ARM_JOINTS[i])]] = q[i];
  d->qpos[m->jnt_qposadr[mj_name2id(m, mjOBJ_JOINT, FINGER_JOINTS[0])]] = f1;
  d->qpos[m->jnt_qposadr[mj_name2id(m, mjOBJ_JOINT, FINGER_JOINTS[1])]] = f2;
  mj_forward(m, d);
}

static int has_contact(const mjModel* m, const mjData* d, int g1, int g2) {
  (void)m;
  for (int i = 0; i < d->ncon; i++) {
    const mjContact* c = d->contact + i;
    if ((c->geom1 == g1 && c->geom2 == g2) || (c->geom1 == g2 && c->geom2 == g1)) return 1;
  }
  return 0;
}

static const char* geom_name(const mjModel* m, int g) {
  const char* n = mj_id2name(m, mjOBJ_GEOM, g);
  return n ? n : "(unnamed)";
}

static void print_contact_pairs(const mjModel* m, const mjData* d, const char* label) {
  for (int i = 0; i < d->ncon; i++) {
    const mjContact* c = d->contact + i;
    int first = 1, count = 0;
    for (int j = 0; j < d->ncon; j++) {
      const mjContact* o = d->contact + j;
      if (o->geom1 == c->geom1 && o->geom2 == c->geom2) {
        if (j < i) first = 0;
        count++;
      }
    }
    if (first)
      printf("    %s: %d contact(s) %s - %s, dist %.4g, dim %d\n", label, count, geom_name(m, c->geom1),
             geom_name(m, c->geom2), c->dist, c->dim);
  }
}

/* A contact pair is expected at rest only between the two fingers' geoms. */
static int is_finger_geom(const mjModel* m, int g) {
  const char* n = geom_name(m, g);
  return strstr(n, "finger") != NULL;
}

static void check_contacts_at_pose(const mjModel* m, mjData* d, const char* label, const double q[7],
                                   double fing) {
  set_arm(m, d, q, fing, fing);
  int unexpected = 0;
  for (int i = 0; i < d->ncon; i++) {
    const mjContact* c = d->contact + i;
    if (!(is_finger_geom(m, c->geom1) && is_finger_geom(m, c->geom2))) {
      unexpected++;
      printf("    unexpected contact %s - %s (dist %.3g)\n", geom_name(m, c->geom1),
             geom_name(m, c->geom2), c->dist);
    }
  }
  check(unexpected == 0, "%s, fingers %.3f: no contacts other than finger-finger (ncon %d)", label,
        fing, d->ncon);
}

static void check_model(const mjModel* m, int has_rod) {
  const double tol = 1e-9;
  printf("-- global settings (docs/original-d3il.md §01.1.2)\n");
  check(m->opt.timestep == 0.001, "timestep 0.001");
  check(m->opt.integrator == mjINT_EULER, "integrator Euler (unset)");
  check(m->opt.solver == mjSOL_NEWTON, "solver Newton");
  check(m->opt.iterations == 100, "iterations 100 (unset)");
  check(m->opt.tolerance == 1e-10, "tolerance 1e-10");
  check(m->opt.cone == mjCONE_ELLIPTIC, "cone elliptic");
  check(m->opt.impratio == 3, "impratio 3");
  check(m->opt.gravity[0] == 0 && m->opt.gravity[1] == 0 && m->opt.gravity[2] == -9.81, "gravity (0,0,-9.81)");
  check(!(m->opt.disableflags & mjDSBL_FILTERPARENT), "parent filter on");
  check(m->opt.disableflags == 0 && m->opt.enableflags == 0, "no option flags changed");
  check(m->nconmax == 2000 && m->njmax == 2000, "nconmax/njmax 2000/2000");
  check(m->vis.quality.offsamples == 16 && m->vis.quality.shadowsize == 8192, "offsamples 16, shadowsize 8192");
  /* mjVisual stores floats. */
  check(near(m->vis.map.znear, 0.001, 1e-9) && near(m->vis.map.zfar, 1000, 1e-4), "znear 0.001, zfar 1000");

  printf("-- sizes and names\n");
  check(m->nq == 9 && m->nv == 9 && m->nu == 9, "nq/nv/nu = %d/%d/%d (expect 9/9/9)", m->nq, m->nv, m->nu);
  int nb_robot = has_rod ? 17 : 15;
  check(m->nbody == 1 + 1 + 1 + 22 + nb_robot, "nbody %d = world+ground+rgbd_cage+22 table+%d robot", m->nbody,
        nb_robot);
  for (int i = 0; i < 7; i++) {
    int j = id_of(m, mjOBJ_JOINT, ARM_JOINTS[i]);
    if (j >= 0) check(m->jnt_dofadr[j] == i && m->jnt_qposadr[j] == i, "%s is DoF %d", ARM_JOINTS[i], i);
  }
  for (int i = 0; i < 2; i++) {
    int j = id_of(m, mjOBJ_JOINT, FINGER_JOINTS[i]);
    if (j >= 0) check(m->jnt_dofadr[j] == 7 + i, "%s is DoF %d", FINGER_JOINTS[i], 7 + i);
  }

  printf("-- joints (docs/original-d3il.md §01.2.2, §01.1.3)\n");
  static const double LO[7] = {-2.9671, -1.8326, -2.9671, -3.1416, -2.9671, -0.0873, -2.9671};
  static const double HI[7] = {2.9671, 1.8326, 2.9671, 0.0873, 2.9671, 3.8223, 2.9671};
  for (int i = 0; i < 7; i++) {
    int j = mj_name2id(m, mjOBJ_JOINT, ARM_JOINTS[i]);
    if (j < 0) continue;
    int dof = m->jnt_dofadr[j];
    check(m->jnt_type[j] == mjJNT_HINGE && m->jnt_limited[j] && m->jnt_range[2 * j] == LO[i] &&
              m->jnt_range[2 * j + 1] == HI[i] && m->jnt_axis[3 * j + 2] == 1 && m->dof_damping[dof] == 0 &&
              m->dof_armature[dof] == 0 && m->dof_frictionloss[dof] == 0,
          "%s hinge z, limited [%g, %g], no damping/armature/friction", ARM_JOINTS[i], LO[i], HI[i]);
  }
  for (int i = 0; i < 2; i++) {
    int j = mj_name2id(m, mjOBJ_JOINT, FINGER_JOINTS[i]);
    if (j < 0) continue;
    double sgn = i == 0 ? 1 : -1;
    check(m->jnt_type[j] == mjJNT_SLIDE && m->jnt_limited[j] && m->jnt_range[2 * j] == 0 &&
              m->jnt_range[2 * j + 1] == 0.04 && m->jnt_axis[3 * j + 1] == sgn &&
              m->dof_damping[m->jnt_dofadr[j]] == 10,
          "%s slide along (0,%+g,0), limited [0, 0.04], damping 10", FINGER_JOINTS[i], sgn);
  }

  printf("-- actuators (docs/original-d3il.md §01.2.4)\n");
  static const char* ACT[9] = {"panda_rb0_joint1_act", "panda_rb0_joint2_act", "panda_rb0_joint3_act",
                               "panda_rb0_joint4_act", "panda_rb0_joint5_act", "panda_rb0_joint6_act",
                               "panda_rb0_joint7_act", "panda_rb0_finger_joint1_act",
                               "panda_rb0_finger_joint2_act"};
  static const double FR[9] = {87, 87, 87, 87, 12, 12, 12, 70, 70};
  for (int a = 0; a < 9; a++) {
    int id = id_of(m, mjOBJ_ACTUATOR, ACT[a]);
    if (id < 0) continue;
    const char* jn = a < 7 ? ARM_JOINTS[a] : FINGER_JOINTS[a - 7];
    check(id == a && m->actuator_trntype[id] == mjTRN_JOINT &&
              m->actuator_trnid[2 * id] == mj_name2id(m, mjOBJ_JOINT, jn) && m->actuator_gear[6 * id] == 1 &&
              m->actuator_gainprm[mjNGAIN * id] == 1 && m->actuator_biastype[id] == mjBIAS_NONE &&
              m->actuator_dyntype[id] == mjDYN_NONE && !m->actuator_ctrllimited[id] &&
              m->actuator_forcelimited[id] && m->actuator_forcerange[2 * id] == -FR[a] &&
              m->actuator_forcerange[2 * id + 1] == FR[a],
          "actuator %d %s -> %s, motor gear 1, ctrl unlimited, force +-%g", a, ACT[a], jn, FR[a]);
  }

  printf("-- inertials (docs/original-d3il.md §01.2.3)\n");
  static const char* BODY[] = {"panda_rb0_link0", "panda_rb0_link1", "panda_rb0_link2", "panda_rb0_link3",
                               "panda_rb0_link4", "panda_rb0_link5", "panda_rb0_link6", "panda_rb0_link7",
                               "panda_rb0_hand", "panda_rb0_leftfinger", "panda_rb0_rightfinger"};
  static const double MASS[] = {3.01399, 2.77281, 2.7996, 2.14603, 2.18807, 3.19545,
                                1.35761, 0.417345, 0.670782, 0.0218754, 0.0218754};
  for (int i = 0; i < 11; i++) {
    int b = id_of(m, mjOBJ_BODY, BODY[i]);
    if (b >= 0) check(m->body_mass[b] == MASS[i], "%s mass %g", BODY[i], MASS[i]);
  }
  int b = id_of(m, mjOBJ_BODY, "panda_rb0_link8");
  if (b >= 0)
    check(near(m->body_mass[b], 0.1, tol) && near(m->body_inertia[3 * b], 0.1, tol) &&
              near(m->body_inertia[3 * b + 1], 0.1, tol) && near(m->body_inertia[3 * b + 2], 0.1, tol),
          "panda_rb0_link8 mass 0.1, inertia 0.1*I (quirk kept)");
  static const char* TIPS[2] = {"finger_rb0_joint1_tip", "finger_rb0_joint2_tip"};
  for (int i = 0; i < 2; i++) {
    b = id_of(m, mjOBJ_BODY, TIPS[i]);
    if (b >= 0)
      check(near(m->body_mass[b], 0.01, tol) && near(m->body_inertia[3 * b], 0.01, tol) &&
                near(m->body_inertia[3 * b + 1], 0.01, tol) && near(m->body_inertia[3 * b + 2], 0.01, tol),
            "%s mass 0.01, inertia 0.01*I (quirk kept)", TIPS[i]);
  }
  b = id_of(m, mjOBJ_BODY, "tcp_rb0");
  if (b >= 0) check(m->body_mass[b] == 0, "tcp_rb0 massless");
  if (has_rod) {
    b = id_of(m, mjOBJ_BODY, "rod_rb0");
    if (b >= 0) {
      printf("    rod_rb0: mass %.9g, ipos (%.3g, %.3g, %.9g), inertia (%.6g, %.6g, %.6g)\n", m->body_mass[b],
             m->body_ipos[3 * b], m->body_ipos[3 * b + 1], m->body_ipos[3 * b + 2], m->body_inertia[3 * b],
             m->body_inertia[3 * b + 1], m->body_inertia[3 * b + 2]);
      check(near(m->body_mass[b], 0.0942478, 1e-7) && near(m->body_ipos[3 * b + 2], 0.075, 1e-12) &&
                near(m->body_ipos[3 * b], 0, 1e-12) && near(m->body_ipos[3 * b + 1], 0, 1e-12),
            "rod_rb0 inferred mass 0.0942478, COM (0,0,0.075)");
      /* Solid cylinder r = 0.01, length 0.3: I_xx = I_yy = m (3 r^2 + L^2) / 12 = 7.0921e-4, I_zz = m r^2 / 2.
         docs/original-d3il.md §01.2.3 prints "~7.0893e-4", 0.04 % lower than the exact formula MuJoCo uses; the mass and
         COM (which the spec gives exactly) match, so we check the formula and the spec value loosely. */
      double mr = m->body_mass[b], Ixx = mr * (3 * 1e-4 + 0.09) / 12, Izz = mr * 1e-4 / 2;
      double I[3] = {m->body_inertia[3 * b], m->body_inertia[3 * b + 1], m->body_inertia[3 * b + 2]};
      int two_big = 0, one_small = 0;
      for (int k = 0; k < 3; k++) {
        if (near(I[k], Ixx, 1e-12) && near(I[k], 7.0893e-4, 5e-7)) two_big++;
        if (near(I[k], Izz, 1e-14) && near(I[k], 4.712e-6, 1e-9)) one_small++;
      }
      check(two_big == 2 && one_small == 1,
            "rod_rb0 inertia = solid-cylinder formula (%.5e, %.5e, %.4e), spec ~ (7.0893e-4, 7.0893e-4, 4.712e-6)",
            Ixx, Ixx, Izz);
    }
    b = id_of(m, mjOBJ_BODY, "rod:tip_rb0");
    if (b >= 0) {
      printf("    rod:tip_rb0: mass %.9g, ipos z %.9g, inertia %.6g\n", m->body_mass[b], m->body_ipos[3 * b + 2],
             m->body_inertia[3 * b]);
      check(near(m->body_mass[b], 0.00418879, 1e-8) && near(m->body_ipos[3 * b + 2], 0.225, 1e-12) &&
                near(m->body_inertia[3 * b], 1.6755e-7, 1e-11),
            "rod:tip_rb0 inferred mass 0.00418879, COM z 0.225, inertia 1.6755e-7");
    }
    int g = id_of(m, mjOBJ_GEOM, "rod:geom_rb0");
    if (g >= 0)
      check(m->geom_type[g] == mjGEOM_CYLINDER && m->geom_size[3 * g] == 0.01 && m->geom_size[3 * g + 1] == 0.15 &&
                m->geom_contype[g] == 1 && m->geom_conaffinity[g] == 1 && m->geom_condim[g] == 3 &&
                m->geom_margin[g] == 0 && m->geom_solref[2 * g] == 0.02 && m->geom_solimp[5 * g] == 0.9,
            "rod:geom_rb0 cylinder r 0.01 half 0.15, default contact params");
    g = id_of(m, mjOBJ_GEOM, "rod:tip_rb0");
    if (g >= 0)
      check(m->geom_type[g] == mjGEOM_SPHERE && m->geom_contype[g] == 0 && m->geom_conaffinity[g] == 0,
            "rod:tip_rb0 sphere, visual only");
  } else {
    check(mj_name2id(m, mjOBJ_BODY, "rod_rb0") < 0, "gripper variant has no rod");
  }

  printf("-- finger-tip boxes and class defaults (docs/original-d3il.md §01.1.3, §01.2.5)\n");
  static const char* TIPG[2] = {"finger1_rb0_tip_collision", "finger2_rb0_tip_collision"};
  for (int i = 0; i < 2; i++) {
    int g = id_of(m, mjOBJ_GEOM, TIPG[i]);
    if (g < 0) continue;
    check(m->geom_type[g] == mjGEOM_BOX && m->geom_size[3 * g] == 0.008 && m->geom_size[3 * g + 1] == 0.004 &&
              m->geom_size[3 * g + 2] == 0.008 && m->geom_condim[g] == 4 && m->geom_friction[3 * g] == 2 &&
              m->geom_friction[3 * g + 1] == 0.05 && m->geom_friction[3 * g + 2] == 0.0001 &&
              m->geom_solref[2 * g] == 0.01 && m->geom_solref[2 * g + 1] == 0.5 &&
              m->geom_solimp[5 * g] == 0.998 && m->geom_solimp[5 * g + 1] == 0.999 &&
              m->geom_solimp[5 * g + 2] == 0.001 && m->geom_margin[g] == 0.001 && m->geom_contype[g] == 1,
          "%s box (0.008,0.004,0.008), condim 4, friction (2,0.05,1e-4), solref (0.01,0.5), class solimp/margin",
          TIPG[i]);
  }
  static const char* FG[2] = {"panda_rb0_leftfinger:geom2", "panda_rb0_rightfinger:geom2"};
  for (int i = 0; i < 2; i++) {
    int g = id_of(m, mjOBJ_GEOM, FG[i]);
    if (g < 0) continue;
    check(m->geom_condim[g] == 4 && m->geom_margin[g] == 0.001 && m->geom_solimp[5 * g] == 0.998 &&
              m->geom_friction[3 * g] == 1,
          "%s uses class defaults (condim 4, margin 0.001, solimp 0.998..)", FG[i]);
  }
  int tg = id_of(m, mjOBJ_GEOM, "table_plane:geom");
  if (tg >= 0)
    check(m->geom_contype[tg] == 7 && m->geom_conaffinity[tg] == 7 && m->geom_solref[2 * tg] == 0.002 &&
              m->geom_solimp[5 * tg] == 0.999,
          "table_plane:geom contype/conaffinity 7, solref 0.002, solimp 0.999");
  static const char* COLL[] = {"panda_rb0_link0:geom2", "panda_rb0_joint1:geom2", "panda_rb0_joint2:geom2",
                               "panda_rb0_joint3:geom2", "panda_rb0_link4:geom2", "panda_rb0_link5:geom2",
                               "panda_rb0_link6:geom2", "panda_rb0_link7:geom2", "panda_rb0_hand:geom2"};
  int ok_names = 1;
  for (int i = 0; i < 9; i++) {
    int g = mj_name2id(m, mjOBJ_GEOM, COLL[i]);
    char vis[128];
    snprintf(vis, sizeof vis, "%.*s1", (int)strlen(COLL[i]) - 1, COLL[i]);
    int gv = mj_name2id(m, mjOBJ_GEOM, vis);
    if (g < 0 || gv < 0 || m->geom_contype[g] != 1 || m->geom_conaffinity[g] != 1 || m->geom_contype[gv] != 0 ||
        m->geom_conaffinity[gv] != 0 || m->geom_group[gv] != 1) {
      ok_names = 0;
      printf("    bad collision/visual pair %s / %s\n", COLL[i], vis);
    }
  }
  check(ok_names, "link/hand :geom1 (visual, group 1, no contact) and :geom2 (collision) pairs present");

  printf("-- cameras (docs/original-d3il.md §01.6)\n");
  int c = id_of(m, mjOBJ_CAMERA, "rgbd_rb0");
  if (c >= 0) {
    const mjtNum* q = m->cam_quat + 4 * c;
    check(near(q[0], 0.000563, 2e-6) && near(q[1], 0.706825, 2e-6) && near(q[2], 0.707388, 2e-6) &&
              near(q[3], 0.000563, 2e-6) && near(m->cam_fovy[c], 60, 1e-12) &&
              m->cam_bodyid[c] == mj_name2id(m, mjOBJ_BODY, "panda_rb0_hand") && near(m->cam_pos[3 * c], 0.1, 1e-12),
          "rgbd_rb0 on panda_rb0_hand, pos (0.1,0,0), quat (%.6f, %.6f, %.6f, %.6f), fovy 60", q[0], q[1], q[2], q[3]);
  }
  c = id_of(m, mjOBJ_CAMERA, "rgbd_cage");
  if (c >= 0) check(near(m->cam_fovy[c], 45, 1e-12), "rgbd_cage fovy 45");
}

static void check_kinematics_and_contacts(const mjModel* m, int has_rod) {
  mjData* d = mj_makeData(m);
  int tcp = mj_name2id(m, mjOBJ_BODY, "tcp_rb0");

  printf("-- TCP at each task's init_qpos (docs/original-d3il.md §01.4.5; reference is one substep stale)\n");
  for (size_t i = 0; i < sizeof INIT_POSES / sizeof INIT_POSES[0]; i++) {
    set_arm(m, d, INIT_POSES[i].q, 0, 0);
    const mjtNum* p = d->xpos + 3 * tcp;
    double e = 0;
    for (int k = 0; k < 3; k++) e = fmax(e, fabs(p[k] - INIT_POSES[i].tcp[k]));
    check(e < 1e-5, "%s: tcp_rb0 xpos (%.9f, %.9f, %.9f), max |diff| %.2e", INIT_POSES[i].task, p[0], p[1], p[2],
          e);
  }
  set_arm(m, d, INIT_POSES[0].q, 0, 0);
  {
    const mjtNum* q = d->xquat + 4 * tcp;
    double s = q[1] < 0 ? -1 : 1;
    check(near(s * q[0], -7.8e-5, 2e-5) && near(s * q[1], 0.9999992, 2e-6) && near(s * q[2], -1.16e-4, 2e-5) &&
              near(s * q[3], 1.275e-3, 2e-5),
          "Avoiding: tcp_rb0 xquat (%.3e, %.7f, %.3e, %.4e) ~ (-7.8e-5, 0.9999992, -1.16e-4, 1.275e-3)", s * q[0],
          s * q[1], s * q[2], s * q[3]);
  }
  {
    /* rgbd_cage: view direction (-0.5, 0, -0.866), image-right +y (docs/original-d3il.md §01.6). */
    int c = mj_name2id(m, mjOBJ_CAMERA, "rgbd_cage");
    const mjtNum* R = d->cam_xmat + 9 * c;
    const mjtNum* p = d->cam_xpos + 3 * c;
    check(near(-R[2], -0.5, 1e-6) && near(-R[5], 0, 1e-6) && near(-R[8], -0.866025, 1e-6) && near(R[0], 0, 1e-6) &&
              near(R[3], 1, 1e-6) && near(p[0], 0.7, 1e-12) && near(p[1], 0.1, 1e-12) && near(p[2], 0.9, 1e-12),
          "rgbd_cage at (0.7,0.1,0.9) looks along (%.4f, %.4f, %.4f), image-right world +y", -R[2], -R[5], -R[8]);
  }

  printf("-- contacts (docs/original-d3il.md §01.2.5)\n");
  int t1 = mj_name2id(m, mjOBJ_GEOM, "finger1_rb0_tip_collision");
  int t2 = mj_name2id(m, mjOBJ_GEOM, "finger2_rb0_tip_collision");
  int f1 = mj_name2id(m, mjOBJ_GEOM, "panda_rb0_leftfinger:geom2");
  int f2 = mj_name2id(m, mjOBJ_GEOM, "panda_rb0_rightfinger:geom2");
  int hand = mj_name2id(m, mjOBJ_GEOM, "panda_rb0_hand:geom2");
  set_arm(m, d, INIT_POSES[0].q, 0, 0);
  print_contact_pairs(m, d, "fingers at 0 (box-box dist is half the overlap in MuJoCo)");
  check(has_contact(m, d, t1, t2), "fingers at 0: the two finger-tip boxes are in contact");
  /* MuJoCo's box-box collider reports half the face-face overlap as dist, so check the geometry
     itself: tip box centre (0, +-(q_f + 0.0035), 0.1024) in the hand frame, inner face at |y| = q_f - 0.0005,
     lowest point z = 0.1104; finger box inner face 0.4 mm behind, lowest point 0.1123 (docs/original-d3il.md §01.2.5, §01.2.6). */
  {
    const double qf = 0.013;
    set_arm(m, d, INIT_POSES[0].q, qf, qf);
    int hb = mj_name2id(m, mjOBJ_BODY, "panda_rb0_hand");
    int gs[4] = {t1, t2, f1, f2};
    double inner[4], low[4], cy[4], cz[4];
    for (int k = 0; k < 4; k++) {
      int g = gs[k];
      mjtNum rel[3], loc[3], Rh[9], Rrel[9];
      mju_sub3(rel, d->geom_xpos + 3 * g, d->xpos + 3 * hb);
      mju_copy(Rh, d->xmat + 9 * hb, 9);
      mju_mulMatTVec(loc, Rh, rel, 3, 3);
      mju_mulMatTMat(Rrel, Rh, d->geom_xmat + 9 * g, 3, 3, 3);
      /* half-extent of the box along hand y and hand z */
      double hy = 0, hz = 0;
      for (int a = 0; a < 3; a++) {
        hy += fabs(Rrel[3 + a]) * m->geom_size[3 * g + a];
        hz += fabs(Rrel[6 + a]) * m->geom_size[3 * g + a];
      }
      cy[k] = loc[1];
      cz[k] = loc[2];
      inner[k] = fabs(loc[1]) - hy;
      low[k] = loc[2] + hz;
    }
    check(near(cy[0], qf + 0.0035, 1e-9) && near(cy[1], -(qf + 0.0035), 1e-9) && near(cz[0], 0.1024, 1e-9) &&
              near(cz[1], 0.1024, 1e-9),
          "tip box centres in the hand frame (0, %+.4f / %+.4f, %.4f) at q_f = %.3f", cy[0], cy[1], cz[0], qf);
    check(near(inner[0], qf - 0.0005, 1e-9) && near(inner[1], qf - 0.0005, 1e-9) && near(low[0], 0.1104, 1e-9),
          "tip box inner faces at |y| = q_f - 0.0005, lowest point z = 0.1104");
    check(near(inner[2] - inner[0], 0.0004, 1e-9) && near(inner[3] - inner[1], 0.0004, 1e-9) &&
              near(low[2], 0.1123, 1e-9),
          "finger boxes: inner face 0.4 mm behind the tip box face, lowest point z = 0.1123");
    set_arm(m, d, INIT_POSES[0].q, 0, 0);
  }
  int hand_finger = 0;
  int fg[4] = {t1, t2, f1, f2};
  for (int k = 0; k < 4; k++) hand_finger |= has_contact(m, d, hand, fg[k]);
  check(!hand_finger, "no hand-finger contacts although the hand box overlaps the finger boxes (parent filter)");
  if (has_rod) {
    int rod = mj_name2id(m, mjOBJ_GEOM, "rod:geom_rb0");
    int rod_finger = 0;
    for (int k = 0; k < 4; k++) rod_finger |= has_contact(m, d, rod, fg[k]);
    /* The closed finger boxes reach |y| = 0.0001 < rod radius 0.01: geometric overlap, filtered by weld groups. */
    check(!rod_finger, "rod does NOT contact the fingers or tip boxes (fingers closed, overlapping the rod)");
    set_arm(m, d, INIT_POSES[0].q, 0.04, 0.04);
    rod_finger = 0;
    for (int k = 0; k < 4; k++) rod_finger |= has_contact(m, d, rod, fg[k]);
    check(!rod_finger, "rod does NOT contact the fingers (fingers open)");
  }
  set_arm(m, d, INIT_POSES[0].q, 0.04, 0.04);
  check(d->ncon == 0, "fingers open at Avoiding init_qpos: no contacts at all (ncon %d)", d->ncon);
  for (size_t i = 0; i < sizeof INIT_POSES / sizeof INIT_POSES[0]; i++) {
    check_contacts_at_pose(m, d, INIT_POSES[i].task, INIT_POSES[i].q, 0);
    check_contacts_at_pose(m, d, INIT_POSES[i].task, INIT_POSES[i].q, 0.04);
  }
  check_contacts_at_pose(m, d, "q_scene", Q_SCENE, 0);

  if (has_rod) {
    /* Rod against the table: lift the (static) table so the rod end, at z ~ 0.0024, dips in by 0.5 mm,
       then read the mixed contact parameters (docs/original-d3il.md §01.1.3 example). */
    int tb = mj_name2id(m, mjOBJ_BODY, "table_plane");
    int tg = mj_name2id(m, mjOBJ_GEOM, "table_plane:geom");
    int rod = mj_name2id(m, mjOBJ_GEOM, "rod:geom_rb0");
    mjModel* m2 = mj_copyModel(NULL, m);
    set_arm(m, d, INIT_POSES[0].q, 0.04, 0.04);
    double rod_end = 1e9;
    for (int i = 0; i < 1; i++) {
      const mjtNum* R = d->geom_xmat + 9 * rod;
      rod_end = d->geom_xpos[3 * rod + 2] - 0.15 * fabs(R[8]);
    }
    m2->body_pos[3 * tb + 2] += (rod_end + 0.0005) - (-0.019);
    mjData* d2 = mj_makeData(m2);
    set_arm(m2, d2, INIT_POSES[0].q, 0.04, 0.04);
    int seen = 0;
    for (int i = 0; i < d2->ncon; i++) {
      const mjContact* cc = d2->contact + i;
      if (!((cc->geom1 == rod && cc->geom2 == tg) || (cc->geom1 == tg && cc->geom2 == rod))) continue;
      if (seen++) continue;
      printf("    rod-table contact: dist %.3g, dim %d, friction (%g, %g, %g), solref (%g, %g), "
             "solimp (%g, %g, %g, %g, %g)\n",
             cc->dist, cc->dim, cc->friction[0], cc->friction[1], cc->friction[2], cc->solref[0], cc->solref[1],
             cc->solimp[0], cc->solimp[1], cc->solimp[2], cc->solimp[3], cc->solimp[4]);
      check(cc->dim == 3 && near(cc->solref[0], 0.011, 1e-12) && near(cc->solref[1], 1, 1e-12) &&
                near(cc->solimp[0], 0.9495, 1e-12) && near(cc->solimp[1], 0.9745, 1e-12) &&
                near(cc->solimp[2], 0.001, 1e-12) && near(cc->solimp[3], 0.5, 1e-12) &&
                near(cc->solimp[4], 2, 1e-12) && cc->friction[0] == 1,
            "rod end vs table: condim 3, solref (0.011, 1), solimp (0.9495, 0.9745, 0.001, 0.5, 2)");
    }
    check(seen > 0, "rod end reaches the lifted table (rod end at z %.5f)", rod_end);
    mj_deleteData(d2);
    mj_deleteModel(m2);
  }
  mj_deleteData(d);
}

/* §01.3.7 finger law with target w and grasp flag g (rod tasks open every env step). */
static void finger_law(const mjData* d, const int qa[2], const int va[2], double w, int g, double out[2]) {
  double p[2] = {d->qpos[qa[0]], d->qpos[qa[1]]}, pd[2] = {d->qvel[va[0]], d->qvel[va[1]]};
  double mean = 0.5 * (p[0] + p[1]);
  for (int i = 0; i < 2; i++) {
    double f2;
    if (mean - w > 0.005) f2 = g ? -20 : 10 * (-0.2 - pd[i]);
    else f2 = fmin(5, fmax(-5, 500 * (w - p[i]) - 10 * pd[i]));
    out[i] = 500 * (mean - p[i]) + f2;
  }
}

static void check_dynamics(const mjModel* m, int has_rod) {
  printf("-- simulation sanity (%s)\n", has_rod ? "rod" : "gripper");
  mjData* d = mj_makeData(m);
  int qa[2], va[2], arm_q[7], arm_v[7];
  for (int i = 0; i < 2; i++) {
    int j = mj_name2id(m, mjOBJ_JOINT, FINGER_JOINTS[i]);
    qa[i] = m->jnt_qposadr[j];
    va[i] = m->jnt_dofadr[j];
  }
  for (int i = 0; i < 7; i++) {
    int j = mj_name2id(m, mjOBJ_JOINT, ARM_JOINTS[i]);
    arm_q[i] = m->jnt_qposadr[j];
    arm_v[i] = m->jnt_dofadr[j];
  }
  const double* q0 = INIT_POSES[has_rod ? 0 : 3].q;

  /* 1. Zero control for 500 substeps: the arm falls under gravity and hits its limits/table; no NaN. */
  set_arm(m, d, q0, 0, 0);
  int bad = 0, maxcon = 0;
  for (int s = 0; s < 500 && !bad; s++) {
    mju_zero(d->ctrl, m->nu);
    mj_step(m, d);
    maxcon = d->ncon > maxcon ? d->ncon : maxcon;
    bad = !is_finite_vec(d->qpos, m->nq) || !is_finite_vec(d->qvel, m->nv) || !is_finite_vec(d->qacc, m->nv);
  }
  int warn = 0;
  for (int i = 0; i < mjNWARNING; i++) warn += d->warning[i].number;
  int tcp = mj_name2id(m, mjOBJ_BODY, "tcp_rb0");
  check(!bad && warn == 0, "500 substeps, zero ctrl: finite state, %d MuJoCo warnings, max ncon %d, tcp z %.4f",
        warn, maxcon, d->xpos[3 * tcp + 2]);

  /* 2. Spec hold: reset at q_scene, beam to init_qpos, joint PD + stale qfrc_bias (docs/original-d3il.md §01.3.5, §01.4.4),
        fingers: one reset substep with target 0.001, then 10 env steps (35 substeps) of "open". */
  static const double KP[7] = {120, 120, 120, 120, 50, 30, 10}, KD[7] = {10, 10, 10, 10, 6, 5, 3};
  set_arm(m, d, Q_SCENE, 0, 0);
  mj_forward(m, d);
  set_arm(m, d, q0, 0, 0); /* beam: mj_resetData + qpos + forward; fingers at 0 */
  double tcp0[3];
  mju_copy3(tcp0, d->xpos + 3 * tcp);
  double fing_after[11][2], maxdev = 0;
  int nsub = has_rod ? 35 : 30;
  bad = 0;
  for (int s = 0; s < 1 + 10 * nsub && !bad; s++) {
    for (int i = 0; i < 7; i++)
      d->ctrl[i] = KP[i] * (q0[i] - d->qpos[arm_q[i]]) - KD[i] * d->qvel[arm_v[i]] + d->qfrc_bias[arm_v[i]];
    double f[2];
    if (s == 0) finger_law(d, qa, va, 0.001, 0, f);
    else finger_law(d, qa, va, 0.04, 0, f);
    d->ctrl[7] = f[0];
    d->ctrl[8] = f[1];
    mj_step(m, d);
    bad = !is_finite_vec(d->qpos, m->nq) || !is_finite_vec(d->qvel, m->nv);
    if (s == 0 || (s - 1) % nsub == nsub - 1) {
      int k = s == 0 ? 0 : (s - 1) / nsub + 1;
      fing_after[k][0] = d->qpos[qa[0]];
      fing_after[k][1] = d->qpos[qa[1]];
    }
    for (int k = 0; k < 3; k++) maxdev = fmax(maxdev, fabs(d->xpos[3 * tcp + k] - tcp0[k]));
  }
  check(!bad, "PD hold + finger opening: finite state");
  printf("    fingers after reset step: %.3g, %.3g; after env steps 1, 2, 3, 5, 10:", fing_after[0][0],
         fing_after[0][1]);
  int ks[5] = {1, 2, 3, 5, 10};
  for (int i = 0; i < 5; i++) printf(" (%.6f, %.6f)", fing_after[ks[i]][0], fing_after[ks[i]][1]);
  printf("\n");
  if (has_rod) {
    /* docs/original-d3il.md §01.8 Test A (there the arm also moves under the IK; here it is held, so compare loosely). */
    /* docs/original-d3il.md §01.8 Test A. There the arm also moves under the IK, which pushes the two fingers apart
       asymmetrically; here the arm is held, so compare the mean of the two fingers. */
    static const double REF[5][2] = {{0.015866, 0.016138}, {0.030042, 0.030144}, {0.036015, 0.036032},
                                     {0.039361, 0.039358}, {0.039995, 0.039991}};
    double e = fabs(fing_after[0][0] - 2.29e-5) + fabs(fing_after[0][1] - 2.29e-5);
    check(e < 2e-7, "fingers after the reset substep %.4g ~ 2.29e-5 (closed fingers pushed apart by the tip contact)",
          fing_after[0][0]);
    double em = 0;
    for (int i = 0; i < 5; i++) {
      double ours = 0.5 * (fing_after[ks[i]][0] + fing_after[ks[i]][1]), ref = 0.5 * (REF[i][0] + REF[i][1]);
      em = fmax(em, fabs(ours - ref));
    }
    check(em < 1e-5, "finger opening (mean of both) follows docs/original-d3il.md §01.8 Test A after env steps 1,2,3,5,10 (max |diff| %.2e)",
          em);
  }
  check(maxdev < 0.01, "PD hold keeps the TCP within 1 cm of its start (max |dev| %.2e m)", maxdev);

  /* 3. Close with the grasp flag (Stacking's "close", docs/original-d3il.md §01.3.6-01.3.7) for 1 s: the tip boxes meet and the
        fully closed gripper settles at about 0.001 per finger (docs/original-d3il.md §01.2.5). */
  bad = 0;
  for (int s = 0; s < 1000 && !bad; s++) {
    for (int i = 0; i < 7; i++)
      d->ctrl[i] = KP[i] * (q0[i] - d->qpos[arm_q[i]]) - KD[i] * d->qvel[arm_v[i]] + d->qfrc_bias[arm_v[i]];
    double f[2];
    finger_law(d, qa, va, 0.0, 1, f);
    d->ctrl[7] = f[0];
    d->ctrl[8] = f[1];
    mj_step(m, d);
    bad = !is_finite_vec(d->qpos, m->nq) || !is_finite_vec(d->qvel, m->nv);
  }
  double p1 = d->qpos[qa[0]], p2 = d->qpos[qa[1]];
  check(!bad && p1 > 0.0005 && p1 < 0.0015 && p2 > 0.0005 && p2 < 0.0015,
        "closed gripper (grasp flag) settles at (%.6f, %.6f) ~ 0.001 per finger", p1, p2);
  mj_deleteData(d);
}

/* ---------------------------------------------------------------------------------------------
 * docs/original-d3il.md §01.8 Test A, end to end on our MJCF: reset (§01.4.4), then the Cartesian tracking controller
 * (§01.3.4) with MuJoCo-MJCF kinematics, stale bias (§01.3.5), finger law (§01.3.7), 35 substeps per step.
 * The spec says MJCF kinematics agree with the reference to <= 3.5e-8 m of TCP on free motion; this
 * exercises every dynamics-relevant number in the robot file (inertials, damping, force ranges,
 * finger contacts), not only the kinematics.
 * ------------------------------------------------------------------------------------------- */

/* Cyclic Jacobi eigen-decomposition of a symmetric 6x6 matrix: A = V diag(w) V^T. */
static void sym_eig6(const double A_in[36], double w[6], double V[36]) {
  double A[36];
  memcpy(A, A_in, sizeof A);
  for (int i = 0; i < 36; i++) V[i] = (i % 7 == 0) ? 1 : 0;
  for (int sweep = 0; sweep < 100; sweep++) {
    double off = 0;
    for (int p = 0; p < 6; p++)
      for (int q = p + 1; q < 6; q++) off += A[6 * p + q] * A[6 * p + q];
    if (off < 1e-40) break;
    for (int p = 0; p < 6; p++)
      for (int q = p + 1; q < 6; q++) {
        double apq = A[6 * p + q];
        if (fabs(apq) < 1e-300) continue;
        double theta = (A[6 * q + q] - A[6 * p + p]) / (2 * apq);
        double t = (theta >= 0 ? 1 : -1) / (fabs(theta) + sqrt(theta * theta + 1));
        double c = 1 / sqrt(t * t + 1), sn = t * c;
        for (int k = 0; k < 6; k++) { /* A <- A G */
          double akp = A[6 * k + p], akq = A[6 * k + q];
          A[6 * k + p] = c * akp - sn * akq;
          A[6 * k + q] = sn * akp + c * akq;
        }
        for (int k = 0; k < 6; k++) { /* A <- G^T A */
          double apk = A[6 * p + k], aqk = A[6 * q + k];
          A[6 * p + k] = c * apk - sn * aqk;
          A[6 * q + k] = sn * apk + c * aqk;
        }
        for (int k = 0; k < 6; k++) {
          double vkp = V[6 * k + p], vkq = V[6 * k + q];
          V[6 * k + p] = c * vkp - sn * vkq;
          V[6 * k + q] = sn * vkp + c * vkq;
        }
      }
  }
  for (int i = 0; i < 6; i++) w[i] = A[7 * i];
}

typedef struct {
  const mjModel* m;
  mjData* kin; /* scratch data for FK and the Jacobian at the IK iterate */
  int tcp, arm_q[7], arm_v[7], fq[2], fv[2];
  double qhat[7];
  int have_qhat;
} CartCtl;

static void fk_jac(CartCtl* c, const double q[7], double x[3], double Q[4], double J[42]) {
  for (int i = 0; i < 7; i++) c->kin->qpos[c->arm_q[i]] = q[i];
  mj_kinematics(c->m, c->kin);
  mj_comPos(c->m, c->kin);
  mju_copy3(x, c->kin->xpos + 3 * c->tcp);
  mju_copy4(Q, c->kin->xquat + 4 * c->tcp);
  int nv = c->m->nv;
  mjtNum* jp = malloc(sizeof(mjtNum) * 3 * nv);
  mjtNum* jr = malloc(sizeof(mjtNum) * 3 * nv);
  mj_jacBody(c->m, c->kin, jp, jr, c->tcp);
  for (int r = 0; r < 3; r++)
    for (int k = 0; k < 7; k++) {
      J[7 * r + k] = jp[nv * r + c->arm_v[k]];
      J[7 * (r + 3) + k] = jr[nv * r + c->arm_v[k]];
    }
  free(jp);
  free(jr);
}

static double clipd(double v, double lo, double hi) { return v < lo ? lo : (v > hi ? hi : v); }

/* One substep of §01.3.4 -> q_d, qd_d. */
static void cart_ik(CartCtl* c, const mjData* d, const double xd[3], const double Qd_in[4], double q_d[7],
                    double qd_d[7]) {
  static const double QMIN[7] = {-2.8973, -1.7628, -2.8973, -3.0718, -2.8973, -0.0175, -2.8973};
  static const double QMAX[7] = {2.8973, 1.7628, 2.0, -0.0698, 2.8973, 3.7525, 2.8973};
  static const double QREST[7] = {0, 0.174, 0, -0.872, 0, 1.222, 0.785};
  static const double KX[3] = {200, 200, 800};
  if (!c->have_qhat) {
    for (int i = 0; i < 7; i++) c->qhat[i] = d->qpos[c->arm_q[i]];
    c->have_qhat = 1;
  }
  double q[7], Qd[4];
  memcpy(q, c->qhat, sizeof q);
  memcpy(Qd, Qd_in, sizeof Qd);
  for (int it = 0; it < 3; it++) {
    double x[3], Q[4], J[42];
    fk_jac(c, q, x, Q, J);
    double dm = 0, dp = 0;
    for (int k = 0; k < 4; k++) {
      dm += (Q[k] - Qd[k]) * (Q[k] - Qd[k]);
      dp += (Q[k] + Qd[k]) * (Q[k] + Qd[k]);
    }
    if (sqrt(dm) > sqrt(dp))
      for (int k = 0; k < 4; k++) Qd[k] = -Qd[k];
    double v[6];
    for (int k = 0; k < 3; k++) v[k] = KX[k] * clipd(xd[k] - x[k], -0.01, 0.01);
    /* e_o = c_w d_v - d_w c_v + c_v x d_v (docs/original-d3il.md §01.3.3) */
    double cv[3] = {Q[1], Q[2], Q[3]}, dv[3] = {Qd[1], Qd[2], Qd[3]}, cr[3];
    mju_cross(cr, cv, dv);
    for (int k = 0; k < 3; k++) v[3 + k] = 30 * clipd(Q[0] * dv[k] - Qd[0] * cv[k] + cr[k], -0.1, 0.1);
    double A[36], w[6], V[36], Ainv[36];
    for (int r = 0; r < 6; r++)
      for (int k = 0; k < 6; k++) {
        double sum = 0;
        for (int j = 0; j < 7; j++) sum += J[7 * r + j] * J[7 * k + j];
        A[6 * r + k] = sum + (r == k ? 1e-12 : 0);
      }
    sym_eig6(A, w, V);
    for (int i = 0; i < 6; i++) w[i] = clipd(w[i], 0.01, 100);
    for (int r = 0; r < 6; r++)
      for (int k = 0; k < 6; k++) {
        double sum = 0;
        for (int i = 0; i < 6; i++) sum += V[6 * r + i] * V[6 * k + i] / w[i];
        Ainv[6 * r + k] = sum;
      }
    double qd0[7], rhs[6], y[6], qd[7];
    for (int j = 0; j < 7; j++) qd0[j] = 40 * clipd(QREST[j] - q[j], -0.2, 0.2);
    for (int r = 0; r < 6; r++) {
      double sum = 0;
      for (int j = 0; j < 7; j++) sum += J[7 * r + j] * qd0[j];
      rhs[r] = v[r] - sum;
    }
    for (int r = 0; r < 6; r++) {
      double sum = 0;
      for (int k = 0; k < 6; k++) sum += Ainv[6 * r + k] * rhs[k];
      y[r] = sum;
    }
    double nrm = 0;
    for (int j = 0; j < 7; j++) {
      double sum = 0;
      for (int r = 0; r < 6; r++) sum += J[7 * r + j] * y[r];
      qd[j] = sum + qd0[j];
      nrm += qd[j] * qd[j];
    }
    nrm = sqrt(nrm);
    if (nrm > 3)
      for (int j = 0; j < 7; j++) qd[j] *= 3 / nrm;
    for (int j = 0; j < 7; j++) q[j] = clipd(q[j] + 0.001 * qd[j], QMIN[j], QMAX[j]);
  }
  for (int j = 0; j < 7; j++) {
    q_d[j] = q[j];
    qd_d[j] = (q[j] - c->qhat[j]) / 0.001;
    c->qhat[j] = q[j];
  }
}

static void substep(CartCtl* c, mjData* d, const double q_d[7], const double qd_d[7], double w, int g) {
  static const double KP[7] = {120, 120, 120, 120, 50, 30, 10}, KD[7] = {10, 10, 10, 10, 6, 5, 3};
  for (int i = 0; i < 7; i++)
    d->ctrl[i] = KP[i] * (q_d[i] - d->qpos[c->arm_q[i]]) + KD[i] * (qd_d[i] - d->qvel[c->arm_v[i]]) +
                 d->qfrc_bias[c->arm_v[i]];
  double f[2];
  finger_law(d, c->fq, c->fv, w, g, f);
  d->ctrl[7] = f[0];
  d->ctrl[8] = f[1];
  mj_step(c->m, d);
}

static void check_test_a(const char* dir) {
  printf("\n== docs/original-d3il.md §01.8 Test A (Avoiding hold, then an 8 cm y step) on panda_rod.xml ==\n");
  mjModel* m = load_vfs(dir, "panda_rod.xml");
  if (!m) {
    check(0, "Test A: model loads");
    return;
  }
  mjData* d = mj_makeData(m);
  CartCtl c = {.m = m, .kin = mj_makeData(m), .tcp = mj_name2id(m, mjOBJ_BODY, "tcp_rb0"), .have_qhat = 0};
  for (int i = 0; i < 7; i++) {
    int j = mj_name2id(m, mjOBJ_JOINT, ARM_JOINTS[i]);
    c.arm_q[i] = m->jnt_qposadr[j];
    c.arm_v[i] = m->jnt_dofadr[j];
  }
  for (int i = 0; i < 2; i++) {
    int j = mj_name2id(m, mjOBJ_JOINT, FINGER_JOINTS[i]);
    c.fq[i] = m->jnt_qposadr[j];
    c.fv[i] = m->jnt_dofadr[j];
  }
  const double* q0 = INIT_POSES[0].q;
  /* §01.4.4 reset: scene qpos, forward twice; beam; one hold substep with finger target 0.001. */
  mj_resetData(m, d);
  for (int i = 0; i < 7; i++) d->qpos[c.arm_q[i]] = Q_SCENE[i];
  mj_forward(m, d);
  mj_forward(m, d);
  for (int i = 0; i < 7; i++) {
    d->qpos[c.arm_q[i]] = q0[i];
    d->qvel[c.arm_v[i]] = 0;
  }
  mj_forward(m, d);
  double zero[7] = {0};
  substep(&c, d, q0, zero, 0.001, 0);
  double z0 = d->xpos[3 * c.tcp + 2];

  static const struct {
    int step;
    double x, y, z;
  } REF[] = {
      {0, 0.524928466, -0.279736728, 0.122359306},  {1, 0.527391345, -0.276939761, 0.122808764},
      {2, 0.527556312, -0.277321468, 0.123610431},  {3, 0.527429411, -0.278203453, 0.124290654},
      {5, 0.527123030, -0.279864680, 0.125150210},  {10, 0.525678095, -0.282201811, 0.124684327},
      {11, 0.514489264, -0.276200666, 0.123796949}, {12, 0.503922645, -0.258571570, 0.122768088},
      {13, 0.500578778, -0.242759975, 0.122228255}, {15, 0.507465455, -0.218701597, 0.121958927},
      {20, 0.531948874, -0.178726410, 0.121774527},
  };
  static const double FREF[6][2] = {{2.29e-5, 2.29e-5}, {0.015866, 0.016138}, {0.030042, 0.030144},
                                    {0.036015, 0.036032}, {0.039361, 0.039358}, {0.039995, 0.039991}};
  static const int FSTEP[6] = {0, 1, 2, 3, 5, 10};
  static const double J10[7] = {-0.41999458, 0.425227924, -0.073605311, -2.051083053, 0.048849179, 2.480547687,
                                0.261997662};
  static const double J20[7] = {-0.254905847, 0.351757395, -0.068931859, -2.180057615, 0.052691416, 2.527560040,
                                0.396449759};
  double max_tcp = 0, max_f = 0, max_j10 = 0, max_j20 = 0;
  int ri = 0, fi = 0;
  for (int step = 0; step <= 20; step++) {
    if (step > 0) {
      double xd[3] = {0.525, step <= 10 ? -0.28 : -0.20, z0}, Qd[4] = {0, 1, 0, 0};
      for (int s = 0; s < 35; s++) {
        double q_d[7], qd_d[7];
        cart_ik(&c, d, xd, Qd, q_d, qd_d);
        substep(&c, d, q_d, qd_d, 0.04, 0);
      }
    }
    const mjtNum* p = d->xpos + 3 * c.tcp; /* current_c_pos: stale by one substep, as in the reference */
    if (ri < (int)(sizeof REF / sizeof REF[0]) && REF[ri].step == step) {
      double e = fmax(fabs(p[0] - REF[ri].x), fmax(fabs(p[1] - REF[ri].y), fabs(p[2] - REF[ri].z)));
      printf("    step %2d: tcp (%.9f, %.9f, %.9f)  ref (%.9f, %.9f, %.9f)  max|diff| %.2e\n", step, p[0], p[1], p[2],
             REF[ri].x, REF[ri].y, REF[ri].z, e);
      max_tcp = fmax(max_tcp, e);
      ri++;
    }
    if (fi < 6 && FSTEP[fi] == step) {
      double f1 = d->qpos[c.fq[0]], f2 = d->qpos[c.fq[1]];
      printf("             fingers (%.6g, %.6g)  ref (%.6g, %.6g)\n", f1, f2, FREF[fi][0], FREF[fi][1]);
      max_f = fmax(max_f, fmax(fabs(f1 - FREF[fi][0]), fabs(f2 - FREF[fi][1])));
      fi++;
    }
    if (step == 10 || step == 20)
      for (int i = 0; i < 7; i++) {
        double e = fabs(d->qpos[c.arm_q[i]] - (step == 10 ? J10[i] : J20[i]));
        if (step == 10) max_j10 = fmax(max_j10, e);
        else max_j20 = fmax(max_j20, e);
      }
  }
  /* docs/original-d3il.md §01.8: with MJCF kinematics the reference agreement is <= 3.5e-8 m TCP and ~1.2e-6 rad joints
     (the six-digit hand quaternion); the finger reference is printed with 5-6 digits. */
  check(max_tcp < 1e-7, "Test A TCP rows (steps 0-20) within 1e-7 m of the reference (max |diff| %.2e)", max_tcp);
  check(max_f < 2e-6, "Test A finger positions within 2e-6 of the reference (max |diff| %.2e)", max_f);
  check(max_j10 < 5e-6 && max_j20 < 5e-6,
        "Test A arm joints after steps 10 and 20 within 5e-6 rad (max |diff| %.2e, %.2e)", max_j10, max_j20);
  mj_deleteData(c.kin);
  mj_deleteData(d);
  mj_deleteModel(m);
}

/* The object marker: one free 6 cm cube placed at z = 0 (1.1 cm inside the table, docs/original-d3il.md §01.1.4) and the task
   camera bp_cam. Free objects must come first in qpos, and the cube must pop up to rest at z ~ 0.011. */
static void check_assembly(const char* dir) {
  printf("\n== assembly with a task object and bp_cam (rod robot) ==\n");
  const char* objects =
      "<body name=\"test_cube\" pos=\"0.5 0.2 0\" quat=\"1 0 0 0\"><freejoint/>"
      "<geom name=\"test_cube:geom\" type=\"box\" size=\"0.03 0.03 0.03\" mass=\"0.1\"/></body>\n"
      "    <body name=\"bp_cam\" pos=\"1.05 0 1.2\" quat=\"0.6830127 0.1830127 0.1830127 0.683012\">"
      "<camera name=\"bp_cam\" fovy=\"45\"/></body>";
  mjModel* m = load_vfs_with(dir, "panda_rod.xml", objects);
  check(m != NULL, "scene with objects compiles");
  if (!m) return;
  int cube = mj_name2id(m, mjOBJ_BODY, "test_cube");
  int j1 = mj_name2id(m, mjOBJ_JOINT, ARM_JOINTS[0]);
  check(m->nq == 16 && m->nv == 15 && m->jnt_qposadr[m->body_jntadr[cube]] == 0 && m->jnt_qposadr[j1] == 7 &&
            m->jnt_dofadr[j1] == 6,
        "free object first in qpos (nq %d, arm qpos starts at %d, dof at %d)", m->nq, m->jnt_qposadr[j1],
        m->jnt_dofadr[j1]);
  check(mj_name2id(m, mjOBJ_CAMERA, "bp_cam") >= 0 && m->ncam == 3, "bp_cam present (ncam %d)", m->ncam);
  mjData* d = mj_makeData(m);
  static const double KP[7] = {120, 120, 120, 120, 50, 30, 10}, KD[7] = {10, 10, 10, 10, 6, 5, 3};
  const double* q0 = INIT_POSES[0].q;
  mj_resetData(m, d);
  for (int i = 0; i < 7; i++) d->qpos[7 + i] = q0[i];
  mj_forward(m, d);
  double z5 = 0;
  int bad = 0;
  for (int s = 0; s < 1000 && !bad; s++) {
    for (int i = 0; i < 7; i++)
      d->ctrl[i] = KP[i] * (q0[i] - d->qpos[7 + i]) - KD[i] * d->qvel[6 + i] + d->qfrc_bias[6 + i];
    mj_step(m, d);
    if (s == 5 * 35 - 1) z5 = d->qpos[2];
    bad = !is_finite_vec(d->qpos, m->nq) || !is_finite_vec(d->qvel, m->nv);
  }
  check(!bad && fabs(d->qpos[2] - 0.011) < 5e-4 && fabs(z5 - 0.011) < 1e-3,
        "cube placed at z = 0 pops out of the table: z %.5f after 5 env steps, %.5f after 1 s (expect ~0.011)", z5,
        d->qpos[2]);
  mj_deleteData(d);
  mj_deleteModel(m);
}

int main(int argc, char** argv) {
  const char* dir = argc > 1 ? argv[1] : "assets/mjcf";
  char ver[16];
  snprintf(ver, sizeof ver, "%d", mj_version());
  printf("check_mjcf: MuJoCo %s, files from %s\n", ver, dir);
  if (mj_version() != 222) printf("  warning: expected MuJoCo 2.2.2 (222)\n");

  static const char* ROBOT[2] = {"panda_rod.xml", "panda_gripper.xml"};
  for (int v = 0; v < 2; v++) {
    int has_rod = v == 0;
    printf("\n== %s ==\n", ROBOT[v]);
    mjModel* m = load_vfs(dir, ROBOT[v]);
    check(m != NULL, "scene compiles from the VFS (root + table.xml + %s)", ROBOT[v]);
    mjModel* md = load_tmpdir(dir, ROBOT[v]);
    check(md != NULL, "scene compiles from a temp directory on disk");
    if (!m) {
      if (md) mj_deleteModel(md);
      continue;
    }
    if (md) {
      int same = md->nbody == m->nbody && md->ngeom == m->ngeom && md->nq == m->nq && md->nu == m->nu;
      for (int i = 0; same && i < m->nbody; i++) same = m->body_mass[i] == md->body_mass[i];
      check(same, "VFS and disk loads give the same model");
      mj_deleteModel(md);
    }
    printf("  nbody %d, ngeom %d, njnt %d, nq %d, nv %d, nu %d, ncam %d, nsensor %d\n", m->nbody, m->ngeom,
           m->njnt, m->nq, m->nv, m->nu, m->ncam, m->nsensor);
    check_model(m, has_rod);
    check_kinematics_and_contacts(m, has_rod);
    check_dynamics(m, has_rod);
    mj_deleteModel(m);
  }
  check_assembly(dir);
  check_test_a(dir);
  printf("\nSUMMARY: %d passed, %d failed\n", g_pass, g_fail);
  return g_fail ? 1 : 0;
}
