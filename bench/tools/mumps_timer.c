/* LD_PRELOAD shim for checking the IPOPT-log counters of bench/ipopt_flags.h: counts MUMPS's
   dmumps_c calls by job (1 analysis, 2 factorization, 3 solve) and their process CPU time, and
   prints them to stderr at exit.

     cc -O2 -shared -fPIC -I/usr/include/mumps_seq bench/tools/mumps_timer.c -o mumps_timer.so -ldl
     LD_PRELOAD=./mumps_timer.so build/bench/monoped_benchmark --benchmark_filter=...
*/
#define _GNU_SOURCE
#include <dlfcn.h>
#include <stdio.h>
#include <time.h>

#include <dmumps_c.h>

static long calls[8];
static double seconds[8];

static double cpu_now(void) {
  struct timespec ts;
  clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &ts);
  return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

void dmumps_c(DMUMPS_STRUC_C* id) {
  static void (*real)(DMUMPS_STRUC_C*) = NULL;
  if (!real) real = (void (*)(DMUMPS_STRUC_C*))dlsym(RTLD_NEXT, "dmumps_c");
  const int job = id->job;
  const int k = job >= 1 && job <= 6 ? job : 0;
  const double t0 = cpu_now();
  real(id);
  seconds[k] += cpu_now() - t0;
  ++calls[k];
}

__attribute__((destructor)) static void report(void) {
  for (int k = 0; k < 8; ++k) {
    if (calls[k] > 0) {
      fprintf(stderr, "mumps_timer: job %d: %ld calls, %.3f s CPU\n", k, calls[k], seconds[k]);
    }
  }
}
