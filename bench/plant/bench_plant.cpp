// Benchmark of the lib/slipmodel Euler plant (prints figures; not a test).
//   bench/plant/run.sh            builds it (python -m host_tools._build bench_plant) and runs on one core
// Figures: Euler steps per second in three regimes, and the wall time of a 2 s run at
// dt = 0.5 ms (4000 steps) both through slip::Plant and through the C ABI sm_simulate.
#include <stdio.h>
#include <stdlib.h>
#include <time.h>

#include <slipmodel/plant.h>

#include "slipmodel_capi.h"  // host_tools/native: the C ABI sm_simulate is timed through

static double now_s() {
  timespec ts;
  clock_gettime(CLOCK_MONOTONIC, &ts);
  return ts.tv_sec + 1e-9 * ts.tv_nsec;
}

static volatile double g_sink;

static double steps_per_s(const char* label, double tau_r, double tau_l, int duty) {
  const long n = 2000000;
  slip::Plant pl;
  double best = 1e30;
  for (int rep = 0; rep < 3; ++rep) {
    pl.reset(0, 0, 0);
    const double t0 = now_s();
    for (long k = 0; k < n; ++k) {
      if ((k & 4095) == 0) pl.reset(0, 0, 0);  // keep the state in the regime of interest
      if (duty) pl.step_duty(tau_r, tau_l, 5e-4);
      else pl.step_torque(tau_r, tau_l, 5e-4);
    }
    const double dt = now_s() - t0;
    g_sink = pl.state().x_m;
    if (dt < best) best = dt;
  }
  const double rate = n / best;
  printf("  %-44s %12.0f steps/s  (%.1f ns/step)\n", label, rate, 1e9 / rate);
  return rate;
}

int main() {
  printf("lib/slipmodel Euler plant benchmark (single thread, best of 3)\n");
  steps_per_s("rolling, torque 0.05/0.03 N m", 0.05, 0.03, 0);
  steps_per_s("slipping turn, torque 0.3/0.1 N m", 0.3, 0.1, 0);
  steps_per_s("duty 0.6/0.3 through the motor model", 0.6, 0.3, 1);

  // 2 s run at dt = 0.5 ms.
  const int reps = 200;
  double best = 1e30;
  for (int rep = 0; rep < reps; ++rep) {
    slip::Plant pl;
    const double t0 = now_s();
    for (int k = 0; k < 4000; ++k) pl.step_torque(0.3, 0.1, 5e-4);
    const double dt = now_s() - t0;
    g_sink = pl.state().x_m;
    if (dt < best) best = dt;
  }
  printf("  2 s run at dt = 0.5 ms (4000 steps), slip::Plant:      %8.1f us\n", best * 1e6);

  const int n = 201;  // 10 ms output rows over 2 s
  double* t = static_cast<double*>(malloc(n * sizeof(double)));
  double* r = static_cast<double*>(malloc(n * sizeof(double)));
  double* l = static_cast<double*>(malloc(n * sizeof(double)));
  double* out = static_cast<double*>(malloc(static_cast<size_t>(n) * sm_out_cols() * sizeof(double)));
  for (int k = 0; k < n; ++k) { t[k] = 0.01 * k; r[k] = 0.3; l[k] = 0.1; }
  best = 1e30;
  for (int rep = 0; rep < reps; ++rep) {
    void* h = sm_plant_new();
    const double t0 = now_s();
    sm_simulate(h, 0, n, t, r, l, 5e-4, out);
    const double dt = now_s() - t0;
    g_sink = out[(n - 1) * sm_out_cols() + 1];
    sm_plant_free(h);
    if (dt < best) best = dt;
  }
  printf("  2 s run at dt = 0.5 ms, C ABI sm_simulate (201 rows):  %8.1f us\n", best * 1e6);
  free(t); free(r); free(l); free(out);
  return 0;
}
