/* Times fdmlab_turns_predict (the exported C header) on one feature row:
 * 1e6 calls, the row nudged each call so none is hoisted; prints µs per call.
 * `fdmlab bench turns-train` fills FDMLAB_ROW with the row's floats. */
#define _POSIX_C_SOURCE 199309L
#include <stdio.h>
#include <time.h>
#include "fdmlab_turns.h"

int main(void) {
    float x[FDMLAB_TURNS_INPUTS] = {FDMLAB_ROW};
    float ang[FDMLAB_TURNS_HORIZONS], cp[FDMLAB_TURNS_HORIZONS];
    volatile float sink = 0;
    struct timespec a, b;
    clock_gettime(CLOCK_MONOTONIC, &a);
    for (int i = 0; i < 1000000; ++i) {
        x[0] += 1e-7f;
        fdmlab_turns_predict(x, ang, cp);
        sink += ang[0] + cp[0];
    }
    clock_gettime(CLOCK_MONOTONIC, &b);
    printf("%.6f\n", ((b.tv_sec - a.tv_sec) * 1e9 + (b.tv_nsec - a.tv_nsec)) / 1e6 / 1e3);
    return sink < -1e30f;
}
