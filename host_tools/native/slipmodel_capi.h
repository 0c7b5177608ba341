// The C ABI over lib/slipmodel (defined in slipmodel_capi.cpp, part of .build/host/libddrobot.so):
// the plant, its parameters, the effect vocabulary, normal forces and tau_max. The one
// declaration of these functions: slipmodel_capi.cpp includes it (the compiler checks every
// definition against it) and host_tools/_cabi.py reads it for the ctypes signatures.
// Negative return codes: -1 unknown key, -2 bad value, -3 bad argument, -4 time not
// increasing; sm_last_error(plant) says why.
#ifndef DDROBOT_SLIPMODEL_CAPI_H
#define DDROBOT_SLIPMODEL_CAPI_H

#ifdef __cplusplus
extern "C" {
#endif

// The effect vocabulary (run-format.md) and each effect's parameters with their defaults.
int sm_effect_count(void);
const char* sm_effect_name(int i);
int sm_effect_param_count(int i);
const char* sm_effect_param_name(int i, int k);
double sm_effect_param_default(int i, int k);
// The plant's parameter keys "robot.<p>" and "motor.<p>".
int sm_param_count(void);
const char* sm_param_name(int i);

void* sm_plant_new(void);
void sm_plant_free(void* p);
const char* sm_last_error(void* p);
int sm_plant_set(void* p, const char* key, double v);
int sm_plant_get(void* p, const char* key, double* out);
int sm_plant_clear_effects(void* p);
int sm_plant_reset(void* p, double x, double y, double phi);
int sm_plant_set_velocity(void* p, double v_m_s, double w_m_s, double omega_rad_s,
                          double dtheta_r_rad_s, double dtheta_l_rad_s);

// Output columns of sm_simulate.
int sm_out_cols(void);
const char* sm_out_col_name(int i);
// mode 0: inputs are torques in N m, 1: duties in [-1, 1]; n rows of sm_out_cols() into out.
int sm_simulate(void* p, int mode, int n, const double* t_s, const double* in_r,
                const double* in_l, double dt_s, double* out);

// II.51 per wheel (0 right, 1 left) and the static normal forces II.27-II.29.
double sm_tau_max(void* p, int wheel);
int sm_normal_forces(void* p, double* N_r, double* N_l, double* N_c);

#ifdef __cplusplus
}
#endif

#endif  // DDROBOT_SLIPMODEL_CAPI_H
