/* LD_PRELOAD shim that watches every dmumps_c call a process makes (IPOPT's MUMPS interface) and
   can write the matrix of chosen numeric factorisations to Matrix Market files.

   Counts, by job: initialisations (-1), analyses (1), numeric factorisations (2), solves (3, with
   the right-hand sides each carries, id->nrhs), terminations (-2); the process CPU time spent in
   each; the ICNTL and CNTL values in force at the first factorisation. At exit it prints one line
   "mumps_probe: {json}" on stderr and, if MUMPS_PROBE_OUT names a file, appends the JSON to it.

   Environment:
     MUMPS_PROBE_OUT=file         append the exit JSON to this file
     MUMPS_PROBE_DUMP=pattern     Matrix Market file of a factorisation's matrix; "%d" in the
                                  pattern is replaced by the factorisation's number (1-based)
     MUMPS_PROBE_DUMP_AT=1,100    the factorisations to write (comma-separated, 1-based)
     MUMPS_PROBE_KEEP=197=1       an experiment, not an observation: sets KEEP(197) = 1 (or any
                                  k=v, comma-separated) before every analysis; MUMPS 5.8.2's
                                  default amalgamation of small fronts, which 5.5.1 leaves off and
                                  IPOPT cannot set

   The matrix is written as IPOPT hands it to MUMPS (id->n, id->nz or id->nnz, 1-based id->irn,
   id->jcn, id->a; IPOPT 3.11 and 3.14 fill nz, irn, jcn and a, sym = 2): entries are mirrored to
   the lower triangle and duplicates are kept (MUMPS sums them), with the ICNTL/CNTL values of
   that call in % comments.

   CasADi opens its IPOPT plugin with RTLD_DEEPBIND, which binds libipopt's dmumps_c to the
   bundled libcoinmumps ahead of any preloaded definition; the shim therefore also wraps dlopen
   and drops RTLD_DEEPBIND, and finds the real dmumps_c in whichever loaded object defines it.

   The DMUMPS_STRUC_C layout differs between MUMPS versions, so build one shim per MUMPS header:
     cc -O2 -shared -fPIC -I/usr/include/mumps_seq bench/tools/mumps_probe.c \
       -o /tmp/mumps_probe_debian.so -ldl
     CASADI=~/.cache/bflow/peers-venv/lib/python3.11/site-packages/casadi
     cc -O2 -shared -fPIC -I$CASADI/include/coin-or/mumps bench/tools/mumps_probe.c \
       -o /tmp/mumps_probe_casadi.so -ldl
   and run, e.g.
     MUMPS_PROBE_DUMP=/tmp/kkt/bflow_bb_%d.mtx MUMPS_PROBE_DUMP_AT=1,100 \
       LD_PRELOAD=/tmp/mumps_probe_debian.so build/bench/peer_problems --problem braking-block ...
*/
#define _GNU_SOURCE
#include <dlfcn.h>
#include <link.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include <dmumps_c.h>

typedef void (*dmumps_fn)(DMUMPS_STRUC_C*);

enum { kSlots = 8 };  // index job + 2 for jobs -2..5
static long calls[kSlots];
static double seconds[kSlots];
static long rhs_total;
static long factorisations;
static int have_first;
static int first_icntl[60];
static double first_cntl[15];
static int first_n;
static long long first_nnz;
static char library_path[512];

static double cpu_now(void) {
  struct timespec ts;
  clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &ts);
  return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

void* dlopen(const char* file, int flags) {
  static void* (*real)(const char*, int) = NULL;
  if (!real) real = (void* (*)(const char*, int))dlsym(RTLD_NEXT, "dlopen");
#ifdef RTLD_DEEPBIND
  flags &= ~RTLD_DEEPBIND;
#endif
  return real(file, flags);
}

struct search {
  void* self;
  dmumps_fn found;
};

static int find_in_object(struct dl_phdr_info* info, size_t size, void* data) {
  (void)size;
  struct search* s = (struct search*)data;
  if (s->found || !info->dlpi_name || !info->dlpi_name[0]) return 0;
  if (!strstr(info->dlpi_name, "mumps")) return 0;
  void* h = dlopen(info->dlpi_name, RTLD_LAZY | RTLD_NOLOAD);
  if (!h) return 0;
  dmumps_fn f = (dmumps_fn)dlsym(h, "dmumps_c");
  if (f && (void*)f != s->self) {
    s->found = f;
    snprintf(library_path, sizeof library_path, "%s", info->dlpi_name);
  }
  return 0;
}

static dmumps_fn real_dmumps(void) {
  static dmumps_fn real = NULL;
  if (real) return real;
  struct search s = {(void*)&dmumps_c, NULL};
  dl_iterate_phdr(find_in_object, &s);
  if (!s.found) {
    s.found = (dmumps_fn)dlsym(RTLD_NEXT, "dmumps_c");
    snprintf(library_path, sizeof library_path, "RTLD_NEXT");
  }
  if (!s.found) {
    fprintf(stderr, "mumps_probe: no dmumps_c found in the process\n");
    abort();
  }
  real = s.found;
  return real;
}

static long long entries(const DMUMPS_STRUC_C* id) {
#if defined(MUMPS_VERSION_MAX_LEN)
  return id->nnz != 0 ? (long long)id->nnz : (long long)id->nz;
#else
  return (long long)id->nz;
#endif
}

static int wanted(long k) {
  const char* at = getenv("MUMPS_PROBE_DUMP_AT");
  if (!at) return 0;
  char buf[256];
  snprintf(buf, sizeof buf, "%s", at);
  for (char* tok = strtok(buf, ","); tok; tok = strtok(NULL, ",")) {
    if (atol(tok) == k) return 1;
  }
  return 0;
}

static void dump(const DMUMPS_STRUC_C* id, long k) {
  const char* pattern = getenv("MUMPS_PROBE_DUMP");
  if (!pattern) return;
  char path[1024];
  const char* p = strstr(pattern, "%d");
  if (p) {
    snprintf(path, sizeof path, "%.*s%ld%s", (int)(p - pattern), pattern, k, p + 2);
  } else {
    snprintf(path, sizeof path, "%s", pattern);
  }
  FILE* f = fopen(path, "w");
  if (!f) {
    fprintf(stderr, "mumps_probe: cannot write %s\n", path);
    return;
  }
  const long long nz = entries(id);
  fprintf(f, "%%%%MatrixMarket matrix coordinate real symmetric\n");
  fprintf(f, "%% factorisation %ld (analyses so far %ld), sym %d, %s\n", k, calls[1 + 2], id->sym,
          library_path);
  fprintf(f, "%% icntl");
  for (int i = 0; i < 40; ++i) fprintf(f, " %d", id->icntl[i]);
  fprintf(f, "\n%% cntl");
  for (int i = 0; i < 7; ++i) fprintf(f, " %.17g", id->cntl[i]);
  fprintf(f, "\n%d %d %lld\n", id->n, id->n, nz);
  for (long long e = 0; e < nz; ++e) {
    int i = id->irn[e], j = id->jcn[e];
    if (i < j) {
      const int t = i;
      i = j;
      j = t;
    }
    fprintf(f, "%d %d %.17g\n", i, j, id->a[e]);
  }
  fclose(f);
}

static void set_keep(DMUMPS_STRUC_C* id) {
  const char* spec = getenv("MUMPS_PROBE_KEEP");
  if (!spec) return;
  char buf[256];
  snprintf(buf, sizeof buf, "%s", spec);
  for (char* tok = strtok(buf, ","); tok; tok = strtok(NULL, ",")) {
    int k = 0, v = 0;
    if (sscanf(tok, "%d=%d", &k, &v) == 2 && k >= 1 && k <= 500) id->keep[k - 1] = v;
  }
}

void dmumps_c(DMUMPS_STRUC_C* id) {
  dmumps_fn real = real_dmumps();
  const int job = id->job;
  if (job == 1 || job == 4 || job == 6) set_keep(id);
  const int slot = job >= -2 && job <= 5 ? job + 2 : -1;
  if (job == 2) {
    ++factorisations;
    if (!have_first) {
      have_first = 1;
      memcpy(first_icntl, id->icntl, sizeof first_icntl);
      memcpy(first_cntl, id->cntl, sizeof first_cntl);
      first_n = id->n;
      first_nnz = entries(id);
    }
    if (wanted(factorisations)) dump(id, factorisations);
  }
  if (job == 3) rhs_total += id->nrhs > 0 ? id->nrhs : 1;
  const double t0 = cpu_now();
  real(id);
  if (slot >= 0) {
    seconds[slot] += cpu_now() - t0;
    ++calls[slot];
  }
}

__attribute__((destructor)) static void report(void) {
  char json[4096];
  int w =
      snprintf(json, sizeof json,
               "{\"library\": \"%s\", \"init\": %ld, \"end\": %ld, \"analyses\": %ld, "
               "\"factorizations\": %ld, \"solves\": %ld, \"rhs\": %ld, "
               "\"analysis_cpu_s\": %.6f, \"factorization_cpu_s\": %.6f, "
               "\"solve_cpu_s\": %.6f, \"keep_override\": \"%s\", "
               "\"first_factorization\": {\"n\": %d, \"nnz\": %lld, \"icntl\": [",
               library_path, calls[-1 + 2], calls[-2 + 2], calls[1 + 2], calls[2 + 2], calls[3 + 2],
               rhs_total, seconds[1 + 2], seconds[2 + 2], seconds[3 + 2],
               getenv("MUMPS_PROBE_KEEP") ? getenv("MUMPS_PROBE_KEEP") : "", first_n, first_nnz);
  for (int i = 0; i < 40 && w < (int)sizeof json; ++i) {
    w += snprintf(json + w, sizeof json - w, "%s%d", i ? ", " : "", first_icntl[i]);
  }
  if (w < (int)sizeof json) w += snprintf(json + w, sizeof json - w, "], \"cntl\": [");
  for (int i = 0; i < 7 && w < (int)sizeof json; ++i) {
    w += snprintf(json + w, sizeof json - w, "%s%.6g", i ? ", " : "", first_cntl[i]);
  }
  if (w < (int)sizeof json) snprintf(json + w, sizeof json - w, "]}}");
  fprintf(stderr, "mumps_probe: %s\n", json);
  const char* out = getenv("MUMPS_PROBE_OUT");
  if (out) {
    FILE* f = fopen(out, "a");
    if (f) {
      fprintf(f, "%s\n", json);
      fclose(f);
    }
  }
}
