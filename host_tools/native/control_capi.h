// The C ABI over lib/control (defined in control_capi.cpp, part of .build/host/libddrobot.so):
// the firmware's cascade, float or fixed point, driven as the firmware drives it. The one
// declaration of these functions: control_capi.cpp includes it (the compiler checks every
// definition against it) and host_tools/_cabi.py reads it for the ctypes signatures.
// Negative return codes and a message from ctl_last_error(h) on bad input.
#ifndef DDROBOT_CONTROL_CAPI_H
#define DDROBOT_CONTROL_CAPI_H

#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

int ctl_abi_version(void);
// JSON: keys (name, unit, default), reference kinds, periods, output columns.
const char* ctl_describe(void);
// The columns of ctl_inner's row.
int ctl_column_count(void);
const char* ctl_column_name(int i);

void* ctl_new(int fixed_point, int clamp_enabled);
void ctl_free(void* h);
const char* ctl_last_error(void* h);
int ctl_set(void* h, const char* key, double value);
// ctl_get also reads (not settable) "ff.m_kg", "ff.I_kgm2": the configured variant's feed-forward
// mass and yaw inertia (ControlConfig m_ff_kg, I_ff_kgm2).
int ctl_get(void* h, const char* key, double* out);
// kind 0 line, 1 arc, 2 figure eight; accel m/s^2, cruise m/s, signed radius m.
int ctl_set_reference(void* h, int kind, double accel_m_s2, double cruise_m_s, double radius_m);
// out[7] = x, y, phi, v, omega, dv, domega of the reference at t_s.
int ctl_reference(void* h, double t_s, double* out, int n);
int ctl_reset(void* h, int32_t enc_r, int32_t enc_l, double x_m, double y_m, double phi_rad);
int ctl_outer(void* h, double t_s);
// Start of an experiment: reset, the outer step at t = 0 and the first command (out as ctl_inner).
int ctl_start(void* h, int32_t enc_r, int32_t enc_l, double x_m, double y_m, double phi_rad,
              double* out, int n);
int ctl_inner(void* h, int32_t enc_r, int32_t enc_l, double dt_s, double* out, int n);
// lib/control's odometry over a series of cumulative counts: the pose after each sample.
int ctl_odometry_series(double r_m, double b_m, int32_t counts_per_rev, int n,
                        const int32_t* enc_r, const int32_t* enc_l, const double* t_s,
                        double x0_m, double y0_m, double phi0_rad,
                        double* x_m, double* y_m, double* phi_rad);

#ifdef __cplusplus
}
#endif

#endif  // DDROBOT_CONTROL_CAPI_H
