/* `fdmlab bench pa`: time 1e6 predictions of the K_A C header (`ka.h`).
 * The including code defines FDMLAB_BENCH_INPUTS (the model's input count) and
 * FDMLAB_BENCH_ROW (one design row, comma-separated) before this text.
 * Prints the mean time per prediction in microseconds. */
#define _POSIX_C_SOURCE 199309L
#include <stdio.h>
#include <time.h>
#include "ka.h"

int main(void) {
  double x[FDMLAB_BENCH_INPUTS] = {FDMLAB_BENCH_ROW};
  volatile double sink = 0;
  struct timespec a, b;
  clock_gettime(CLOCK_MONOTONIC, &a);
  for (int i = 0; i < 1000000; ++i) { x[0] += 1e-9; sink += fdmlab_ka_predict(x); }
  clock_gettime(CLOCK_MONOTONIC, &b);
  printf("%.6f\n", ((b.tv_sec - a.tv_sec) * 1e9 + (b.tv_nsec - a.tv_nsec)) / 1e6 / 1e3);
  return sink < -1e300;
}
