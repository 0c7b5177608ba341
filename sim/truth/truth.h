// The independent truth simulator: THE ONE DELIBERATE SECOND IMPLEMENTATION OF THE ROBOT'S
// PHYSICS in this project (docs/ARCHITECTURE.md, "The physics has one home").
//
// Why a second implementation: the mismatch analyzer fits lib/slipmodel's plant to recordings.
// If its test recordings came from that same plant, a passing test would only show that the
// fitter can invert its own model. This simulator is written independently, with a different
// formulation, so that the analyzer is tested against physics it does not share code with:
//
//   * state: the centre of mass c in WORLD coordinates (X, Y, phi; Vx, Vy, omega) plus the two
//     wheel spins; the mass matrix is diagonal (m, m, I_c, I_wy, I_wy) — lib/slipmodel uses
//     body-frame velocities of the axle centre with a coupled mass matrix;
//   * contacts: velocity-level (impulse-based) Coulomb friction solved by projected
//     Gauss-Seidel over all contacts (two wheels, the caster when it drags, each axle's Coulomb
//     friction), each impulse projected onto its friction disc mu*N*h — lib/slipmodel uses an
//     explicit force law with a direct stick solve and a breakaway rule;
//   * its own integrator (symplectic Euler on the impulse-corrected velocities) and step size
//     (0.2 ms by default; the nominal plant uses 0.5 ms); axle viscous friction implicit.
//   * the normal forces of a real robot's mass layout: the platform's mass (m_r, and a payload)
//     at its centre of mass d ahead of the axle, the wheels' mass on the axle; the caster's
//     load from the pitch balance about the robot's centre of mass at height robot.h (or
//     load_transfer.h), with the ground's forward forces and the reaction of the wheels'
//     spin-up (share sim.spin_share of I_wy, 1 by default: the table's I_wy = 2 I_wz is a thin
//     disc's, all of it spinning with the wheel) — lib/slipmodel's II.27-II.29 put the whole
//     mass at c and leave the pitch balance to its load_transfer effect;
//   * effects beyond the run-format vocabulary: an eccentric wheel (rolling radius varying with
//     the wheel angle), battery sag (supply voltage falling with the current and the charge
//     drawn), and a floor patch of different friction.
//
// The recorder (what the robot's board runs and logs) is by default this project's firmware:
// lib/control's ControllerQ (fixed point) is linked in and driven like the firmware, inner step
// every sim.inner_period (25 ms) with the quantised encoder counts, outer step every second
// tick after the inner step. lib/control uses lib/slipmodel's parameters, tau_max and motor
// inverse — that is the firmware's code, not the truth's physics; nothing in truth.cpp calls
// lib/slipmodel's plant, traction or motor functions. Recorder variants that are NOT the
// firmware (rec.*, pi.*): the truth's own PI wheel-speed loop instead of the cascade; the
// truth's own odometry (exact arc or midpoint rule) updated at the ticks or at the telemetry
// frames; inner periods other than 25 ms; telemetry frame times with jitter. A reference
// of ref.kind 3 is the truth's own segment list (speed ramps, cruises, arcs, stops, turns),
// fed to the cascade in its reference formats.
//
// Motor current: the armature current of the truth's DC motor, I = stall_a (V_eff/supply_v -
// ke_ratio omega/no_load) limited to +-stall_a, with the battery, driver drop, deadband and
// back-EMF acting on V_eff and the same lag as the torque; axle friction acts on the wheel, not
// on this law (hidden columns true_i_r_a, true_i_l_a; host_tools/truth.py logs |I| through the
// Motor Shield R3's 1.65 V/A sense and 10-bit ADC).
//
// Sensors: encoder counts floor(theta*ppr/2pi) read live at each tick and telemetry frame;
// 50 Hz telemetry (phase 2 ms as in src/app.cpp); the camera's exact poses at its own times
// (host_tools/truth.py adds the camera noise and dropouts, lost telemetry frames and wrapped
// headings).
//
// C ABI (ctypes, host_tools/truth.py). Keys: see tr_key_count()/tr_key_name(); negative return
// codes: -1 unknown key, -2 bad value, -3 bad argument; tr_last_error() says why.
#ifndef SIM_TRUTH_TRUTH_H
#define SIM_TRUTH_TRUTH_H

#ifdef __cplusplus
extern "C" {
#endif

void* tr_new(void);
void tr_free(void* h);
const char* tr_last_error(void* h);
int tr_key_count(void);
const char* tr_key_name(int i);
int tr_set(void* h, const char* key, double value);
int tr_get(void* h, const char* key, double* out);
/// The segment list of ref.kind 3: n segments of dur[i] s with targets v[i] m/s, w[i] rad/s.
int tr_set_segments(void* h, int n, const double* dur, const double* v, const double* w);
/// Telemetry columns (tr_tel_cols) and camera/true-pose columns (tr_cam_cols).
int tr_tel_cols(void);
const char* tr_tel_col_name(int i);
int tr_cam_cols(void);
const char* tr_cam_col_name(int i);
/// External plant: the recorder above (board, controller, sensors, telemetry and camera timing)
/// drives another physics engine instead of this file's. fn is a pointer to a function
///   int step(void* user, double t_s, double dt_s, double duty_r, double duty_l, double* state)
/// (passed as void* so that the C ABI stays scalar) called once per simulation step after the
/// board: it gets the duties the board applies now (clipped to [-1, 1], before any actuation
/// delay: the external engine models the whole drive), advances its plant from t_s to
/// t_s + dt_s and writes tr_plant_state_count() values (tr_plant_state_name) at t_s + dt_s;
/// a non-zero return stops the run (-2, "external plant failed"). The true-robot keys of this
/// file's physics (robot.*, motor.* and the effects) are then unused; fn = NULL restores this
/// file's own physics.
int tr_set_plant(void* h, void* fn, void* user);
int tr_plant_state_count(void);
const char* tr_plant_state_name(int i);
/// Run for sim.duration seconds. Fills tel (max_tel rows x tr_tel_cols) and cam (max_cam rows x
/// tr_cam_cols), row-major; *n_tel and *n_cam get the row counts. Returns 0 or a negative code.
int tr_run(void* h, int max_tel, double* tel, int* n_tel, int max_cam, double* cam, int* n_cam);

#ifdef __cplusplus
}
#endif

#endif  // SIM_TRUTH_TRUTH_H
