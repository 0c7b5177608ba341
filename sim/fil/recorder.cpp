// Recorder: the run folder's groundtruth.csv (camera model), plant.csv (true plant state),
// encoder_samples.csv (true counts at the firmware's snapshots) and fil.json (summary).
#include "fil.h"

#include <errno.h>
#include <string.h>
#include <sys/stat.h>
#include <time.h>
#include <unistd.h>

namespace fil {


void Fil::open_recording() {
    if (mkdir(opt.run_dir.c_str(), 0777) && errno != EEXIST) die("cannot create %s: %s", opt.run_dir.c_str(), strerror(errno));
    std::string gp = opt.run_dir + "/groundtruth.csv", pp = opt.run_dir + "/plant.csv";
    if (access(gp.c_str(), F_OK) == 0) die("%s already exists; refusing to overwrite a recorded run", gp.c_str());
    gt_f = fopen(gp.c_str(), "w");
    plant_f = fopen(pp.c_str(), "w");
    snap_f = fopen((opt.run_dir + "/encoder_samples.csv").c_str(), "w");
    adc_f = fopen((opt.run_dir + "/adc_samples.csv").c_str(), "w");
    if (!gt_f || !plant_f || !snap_f || !adc_f) die("cannot write in %s: %s", opt.run_dir.c_str(), strerror(errno));
    fprintf(gt_f, "t_s,x_m,y_m,phi_rad\n");
    if (!opt.cam_unix_csv.empty()) {
        gt_unix_f = fopen(opt.cam_unix_csv.c_str(), "w");
        if (!gt_unix_f) die("cannot write %s: %s", opt.cam_unix_csv.c_str(), strerror(errno));
        fprintf(gt_unix_f, "t_s,x_m,y_m,phi_rad\n");
    }
    fprintf(snap_f, "t_s,counts_true_r,counts_true_l,edges_driven_r,edges_driven_l,boot\n");
    fprintf(adc_f, "t_s,wheel,current_a,sense_v\n");
    fprintf(plant_f, "t_s,x_m,y_m,phi_rad,v_m_s,w_m_s,omega_rad_s,theta_r_rad,theta_l_rad,dtheta_r_rad_s,"
                     "dtheta_l_rad_s,duty_r,duty_l,tau_r_nm,tau_l_nm,slipping_r,slipping_l,enc_pins_r,enc_pins_l,"
                     "counts_true_r,counts_true_l,current_r_a,current_l_a\n");
}

void Fil::close_recording() {
    fclose(gt_f);
    fclose(plant_f);
    fclose(snap_f);
    fclose(adc_f);
    if (gt_unix_f) fclose(gt_unix_f);
    gt_unix_f = nullptr;
    gt_f = plant_f = snap_f = adc_f = nullptr;
}

void Fil::write_plant_row(const slip::PlantState& s, double t) {
    if (!plant_f || t < 0) return;
    fprintf(plant_f,
            "%.6f,%.9f,%.9f,%.9f,%.6f,%.6f,%.6f,%.6f,%.6f,%.6f,%.6f,%.5f,%.5f,%.6f,%.6f,%d,%d,%ld,%ld,%.3f,%.3f,%.6f,%.6f\n",
            t, s.x_m, s.y_m, s.phi_rad, s.v_m_s, s.w_m_s, s.omega_rad_s, s.theta_r_rad, s.theta_l_rad,
            s.dtheta_r_rad_s, s.dtheta_l_rad_s, duty[0], duty[1], s.tau_r_nm, s.tau_l_nm,
            s.slipping_r ? 1 : 0, s.slipping_l ? 1 : 0, pos_now[0], pos_now[1],
            s.theta_r_rad * counts_per_rad(), s.theta_l_rad * counts_per_rad(), plant.current_a(0), plant.current_a(1));
}

// camera samples at board times k / cam_rate inside (t0, t1], interpolated linearly
void Fil::camera(double t0, double x0, double y0, double p0, double t1, double x1, double y1, double p1) {
    if (!gt_f || !board_origin_set) return;
    while (next_cam_t <= t1) {
        double t = next_cam_t;
        next_cam_t += 1.0 / opt.cam_rate;
        if (t < t0 || t < 0) continue;
        if (opt.cam_dropout > 0 && uni(rng) < opt.cam_dropout) { ++gt_missing; continue; }
        double f = t1 > t0 ? (t - t0) / (t1 - t0) : 1.0;
        double x = x0 + f * (x1 - x0), y = y0 + f * (y1 - y0), ph = p0 + f * (p1 - p0);
        if (opt.cam_xy > 0) { x += opt.cam_xy * gauss(rng); y += opt.cam_xy * gauss(rng); }
        if (opt.cam_phi > 0) ph += opt.cam_phi * gauss(rng);
        fprintf(gt_f, "%.6f,%.6f,%.6f,%.6f\n", t, x, y, ph);
        if (gt_unix_f) {
            // a tracker on the host stamps a sample when it arrives: the wall clock now, less the
            // board time that has passed since the sample's instant (at most one plant step)
            struct timespec now;
            clock_gettime(CLOCK_REALTIME, &now);
            double unix_s = static_cast<double>(now.tv_sec) + 1e-9 * static_cast<double>(now.tv_nsec) - (board_now() - t);
            fprintf(gt_unix_f, "%.6f,%.6f,%.6f,%.6f\n", unix_s, x, y, ph);
        }
        ++gt_rows;
    }
}

namespace {
void json_str(FILE* f, const std::string& s) {
    fputc('"', f);
    for (char c : s) {
        if (c == '"' || c == '\\') fputc('\\', f);
        if (static_cast<unsigned char>(c) < 0x20) fprintf(f, "\\u%04x", c);
        else fputc(c, f);
    }
    fputc('"', f);
}
}  // namespace

void Fil::write_summary(double wall_s) {
    std::string path = opt.run_dir + "/fil.json";
    FILE* f = fopen(path.c_str(), "w");
    if (!f) die("cannot write %s: %s", path.c_str(), strerror(errno));
    double sim_s = static_cast<double>(avr->cycle) / kF;
    fprintf(f, "{\n  \"format\": \"fil/1\",\n  \"elf\": ");
    json_str(f, opt.elf);
    fprintf(f, ",\n  \"stop_reason\": ");
    json_str(f, stop_reason);
    fprintf(f, ",\n  \"sim_s\": %.6f,\n  \"board_t_end_s\": %.6f,\n  \"wall_s\": %.3f,\n  \"wall_waiting_for_host_s\": %.3f,\n",
            sim_s, board_now(), wall_s, wall_waiting);
    double run_wall = wall_s - wall_waiting;
    fprintf(f, "  \"realtime_limit\": %g,\n  \"sim_s_per_wall_s\": %.4f,\n", opt.realtime,
            run_wall > 0 ? sim_s / run_wall : 0.0);
    fprintf(f, "  \"lockstep\": %s,\n  \"lockstep_holds\": %lu,\n", opt.lockstep ? "true" : "false", holds);
    fprintf(f, "  \"plant_dt_s\": %g,\n  \"plant_steps\": %lu,\n  \"plant_keys\": {", opt.plant_dt, plant_steps);
    for (size_t i = 0; i < opt.keys.size(); ++i) {
        fprintf(f, "%s", i ? ", " : "");
        json_str(f, opt.keys[i].first);
        fprintf(f, ": %.17g", opt.keys[i].second);
    }
    fprintf(f, "},\n");
    fprintf(f, "  \"isr_cycles\": {");
    bool first = true;
    for (int v = 0; v < AVRSIM_VECTORS; ++v) {
        const avrsim_isr_stat_t& st = sim.isr[v];
        if (!st.calls) continue;
        fprintf(f, "%s\n    \"%d\": {\"calls\": %lu, \"max\": %lu, \"mean\": %.2f}", first ? "" : ",", v,
                st.calls, st.max_cycles, st.sum_cycles / static_cast<double>(st.calls));
        first = false;
    }
    fprintf(f, "\n  },\n  \"isr_nested_calls\": %lu,\n", sim.nested_calls);
    avrsim_isr_stat_t enc = {0, 0, 0.0};
    for (int v = 0; v < AVRSIM_VECTORS; ++v) {
        if (!SIM_IS_ENC_VECTOR(v)) continue;
        enc.calls += sim.isr[v].calls;
        enc.sum_cycles += sim.isr[v].sum_cycles;
        if (sim.isr[v].max_cycles > enc.max_cycles) enc.max_cycles = sim.isr[v].max_cycles;
    }
    fprintf(f, "  \"encoder_isr\": {\"edges_driven\": %lu, \"calls\": %lu, \"max_cycles\": %lu, \"mean_cycles\": %.2f},\n",
            edges_total[0] + edges_total[1], enc.calls, enc.max_cycles,
            enc.calls ? enc.sum_cycles / static_cast<double>(enc.calls) : 0.0);
    // the firmware resets its task statistics at Start: "experiment" = frames with status running
    const char* tn[3] = {"inner", "outer", "telemetry"};
    fprintf(f, "  \"tasks\": {");
    for (int i = 0; i < 3; ++i)
        fprintf(f, "%s\"%s\": {\"max_cycles\": %u, \"overruns\": %u, \"experiment_max_cycles\": %u, "
                   "\"experiment_overruns\": %u}", i ? ", " : "", tn[i], task_max[i], task_overruns_max[i],
                task_max_run[i], task_overruns_run[i]);
    fprintf(f, ", \"running_frames\": %lu},\n", running_frames);
    fprintf(f, "  \"encoder_check\": {\"frames\": %lu, \"max_abs_err_counts_r\": %.4f, \"max_abs_err_counts_l\": %.4f,"
               " \"illegal_max_r\": %u, \"illegal_max_l\": %u, \"jitter_us\": %g, \"glitch_p\": %g, \"pin_conflicts\": %lu,\n    \"snapshot_calls\": %lu, \"frames_counts_not_edges_driven\": %lu, \"max_snapshot_to_t_us_s\": %.7f},\n",
            enc_checked, enc_err_max[0], enc_err_max[1], illegal_max[0], illegal_max[1], opt.enc_jitter_us, opt.enc_glitch,
            pin_conflicts, snap_calls, enc_pin_mismatch, snap_lag_max);
    fprintf(f, "  \"current_sense\": {\"samples\": %lu, \"max_abs_current_r_a\": %.6f, \"max_abs_current_l_a\": %.6f},\n",
            adc_samples, sense_max_a[0], sense_max_a[1]);
    fprintf(f, "  \"slip\": {\"steps_slipping_r\": %lu, \"steps_slipping_l\": %lu, \"max_slip_speed_m_s\": %.6f},\n",
            steps_slipping[0], steps_slipping[1], max_slip_speed);
    const slip::PlantState& s = plant.state();
    fprintf(f, "  \"final_pose\": {\"x_m\": %.6f, \"y_m\": %.6f, \"phi_rad\": %.6f, \"theta_r_rad\": %.6f, \"theta_l_rad\": %.6f},\n",
            s.x_m, s.y_m, s.phi_rad, s.theta_r_rad, s.theta_l_rad);
    auto list = [&](const char* name, const std::vector<double>& v) {
        fprintf(f, "  \"%s\": [", name);
        for (size_t i = 0; i < v.size(); ++i) fprintf(f, "%s%.6f", i ? ", " : "", v[i]);
        fprintf(f, "],\n");
    };
    list("brake_on_t_s", brake_on_t);
    list("brake_off_t_s", brake_off_t);
    list("boot_t_s", boot_at_s);
    list("reset_t_s", reset_at_s);
    fprintf(f, "  \"failsafe_events\": [");
    for (size_t i = 0; i < failsafe_events.size(); ++i)
        fprintf(f, "%s{\"t_s\": %.6f, \"code\": %u, \"boot\": %u}", i ? ", " : "", failsafe_events[i].t,
                failsafe_events[i].code, failsafe_events[i].boot);
    fprintf(f, "],\n  \"reset_causes\": [");
    for (size_t i = 0; i < reset_causes.size(); ++i)
        fprintf(f, "%s{\"t_s\": %.6f, \"mcusr\": %u}", i ? ", " : "", reset_causes[i].first, reset_causes[i].second);
    fprintf(f, "],\n  \"experiment_start_t_s\": %.6f,\n  \"hang\": {\"at_s\": %g, \"after_start_s\": %g, \"set_t_s\": %.6f, \"symbol_addr\": %ld},\n",
            run_start_t, opt.hang_at, opt.hang_after_run, hang_t, hang_addr);
    fprintf(f, "  \"frames_from_robot\": {\"telemetry\": %lu, \"params\": %lu, \"ack\": %lu, \"seq_restarts\": %lu},\n",
            telem_frames, params_frames, ack_frames, seq_restarts);
    fprintf(f, "  \"link\": {\"pty\": ");
    json_str(f, pty_name);
    fprintf(f, ", \"baud\": %.1f, \"ber\": %g, \"drop\": %g, \"up\": %s, \"down\": %s,\n"
               "    \"up_bytes\": %lu, \"up_flipped\": %lu, \"up_dropped\": %lu, \"up_unsent\": %lu,\n"
               "    \"down_bytes\": %lu, \"down_flipped\": %lu, \"down_dropped\": %lu, \"down_silenced\": %lu,\n"
               "    \"host_silent_at_s\": %g, \"host_silent_after_start_s\": %g, \"last_down_byte_t_s\": %.6f, \"last_down_frame_t_s\": %.6f,\n"
               "    \"down_frames\": %lu, \"down_frames_corrupted\": %lu, \"down_corrupted_seqs\": [",
            kF / (8.0 * (XBEE_UBRR + 1)), opt.link_ber, opt.link_drop, opt.link_up ? "true" : "false",
            opt.link_down ? "true" : "false", link.up_bytes, link.up_flipped, link.up_dropped, link.up_unsent,
            link.down_bytes, link.down_flipped, link.down_dropped, link.down_silenced, opt.host_silent_at, opt.silent_after_run,
            link.last_down_byte_t, link.last_down_frame_t, down_frames_total, down_frames_corrupted);
    for (size_t i = 0; i < down_corrupted_seqs.size(); ++i) fprintf(f, "%s%u", i ? ", " : "", down_corrupted_seqs[i]);
    fprintf(f, "]},\n  \"groundtruth\": {\"rate_hz\": %g, \"noise_xy_m\": %g, \"noise_phi_rad\": %g, \"dropout\": %g, "
               "\"rows\": %lu, \"missing\": %lu},\n",
            opt.cam_rate, opt.cam_xy, opt.cam_phi, opt.cam_dropout, gt_rows, gt_missing);
    fprintf(f, "  \"pwm_model\": \"%s\",\n  \"seed\": %u\n}\n", opt.pwm_ideal ? "ideal" : "hardware", opt.seed);
    fclose(f);
}

}  // namespace fil
