// The C ABI over lib/closedloop (defined in closedloop_capi.cpp, part of
// .build/host/libddrobot.so): the firmware's cascade in closed loop with the lib/slipmodel
// plant, stepped forward tick by tick. The one declaration of these functions:
// closedloop_capi.cpp includes it (the compiler checks every definition against it) and
// host_tools/_cabi.py reads it for the ctypes signatures. Keys and use: closedloop_capi.cpp.
#ifndef DDROBOT_CLOSEDLOOP_CAPI_H
#define DDROBOT_CLOSEDLOOP_CAPI_H

#ifdef __cplusplus
extern "C" {
#endif

void* cl_new(int fixed_point, int clamp_enabled);
void cl_free(void* h);
const char* cl_last_error(void* h);
// Columns of a tick row and of a plant row.
int cl_tick_col_count(void);
const char* cl_tick_col_name(int i);
int cl_row_col_count(void);
const char* cl_row_col_name(int i);
int cl_set(void* p, const char* key, double value);
int cl_set_reference(void* p, int kind, double accel_m_s2, double cruise_m_s, double radius_m);
int cl_set_drive(void* p, double accel_m_s2, double alpha_rad_s2, int n, const double* t_s,
                 const double* v_m_s, const double* omega_rad_s);
int cl_reset(void* p, double x_m, double y_m, double phi_rad);
int cl_run(void* p, int n, double* ticks, int tick_cols, double* rows, int row_cols);
int cl_state(void* p, double* out, int n);

#ifdef __cplusplus
}
#endif

#endif  // DDROBOT_CLOSEDLOOP_CAPI_H
