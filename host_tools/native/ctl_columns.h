// The controller's output columns, named once: ctl_inner's row (control_capi.cpp) and the
// controller part of the closed-loop driver's tick row (closedloop_capi.cpp), in this order.
#ifndef DDROBOT_CTL_COLUMNS_H
#define DDROBOT_CTL_COLUMNS_H

namespace ctlcols {

static const char* const kNames[] = {
    "pwm_r",     "pwm_l",     "tau_cmd_r", "tau_cmd_l",   "tau_max_r", "tau_max_l",
    "clamped_r", "clamped_l", "sat_r",     "sat_l",       "omega_r",   "omega_l",
    "x_odo_m",   "y_odo_m",   "phi_odo_rad", "v_d_m_s",   "omega_d_rad_s", "e_x_m",
    "e_y_m",     "e_phi_rad", "odo_status", "pwm_slope_r", "pwm_slope_l"};
static const int kCount = static_cast<int>(sizeof(kNames) / sizeof(kNames[0]));

}  // namespace ctlcols

#endif  // DDROBOT_CTL_COLUMNS_H
