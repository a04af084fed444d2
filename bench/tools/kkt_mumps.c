/* Factorises symmetric Matrix Market matrices (the KKT matrices bench/tools/mumps_probe.c writes)
   with MUMPS as IPOPT's MUMPS interface calls it, and times each phase.

   For every matrix and every requested ordering ICNTL(7): sym = 2, ICNTL(6) permuting scaling,
   ICNTL(8) scaling, ICNTL(10) = 0 (no refinement), ICNTL(13) = 1, ICNTL(14) = 1000, CNTL(1) pivot
   tolerance (IPOPT's defaults 7, 77, 1e-6; flags below change them); then the analysis (job 1),
   the numeric factorisation (job 2) and the solve (job 3, one right-hand side of ones) are each
   repeated --reps times on the same instance and the median process CPU time (and wall time) of
   one call is reported. Prints one JSON line per (library, matrix, ordering) on stdout, with the
   factor size and flops MUMPS reports (INFOG(3) estimated and INFOG(9) actual real entries of
   the factors, INFOG(10) integer entries, INFOG(29) effective factor entries, RINFOG(1) and
   RINFOG(3) estimated and actual elimination flops), the inertia (INFOG(12) negative pivots),
   delayed pivots (INFOG(13)), the elimination tree's nodes (INFOG(6)) and largest front
   (INFOG(5)), the ordering MUMPS used (INFOG(7)), the effective ICNTL(6), ICNTL(12)
   and ICNTL(8) (INFOG(23), INFOG(24), INFOG(33)) and the solution's residual
   max|A x - b|. An ordering the library lacks shows as "available": false (MUMPS then falls back
   to another one, named in ordering_used).

   The same source builds against Debian's MUMPS and against the one bundled with CasADi:
     cc -O2 -I/usr/include/mumps_seq bench/tools/kkt_mumps.c -o /tmp/kkt_mumps_debian \
       -ldmumps_seq -lm
     CASADI=~/.cache/bflow/peers-venv/lib/python3.11/site-packages/casadi
     cc -O2 -I$CASADI/include/coin-or/mumps bench/tools/kkt_mumps.c -o /tmp/kkt_mumps_casadi \
       $CASADI/libcoinmumps.so -Wl,-rpath,$CASADI -lm
   and run (single-threaded BLAS):
     OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 /tmp/kkt_mumps_debian --reps 200 \
       --orderings 0,2,3,4,5,6,7 /tmp/kkt/bflow_bb_1.mtx /tmp/kkt/nosnoc_bb_1.mtx
   Flags: --reps N, --phase-reps a,f,s (repetitions per phase, e.g. for profiling one phase),
   --orderings list, --pivtol x (CNTL(1)), --scaling s (ICNTL(8)),
   --permuting-scaling p (ICNTL(6)), --mem-percent m (ICNTL(14), IPOPT's mumps_mem_percent),
   --keep k=v (KEEP(k) = v after initialisation, repeatable: MUMPS' internal controls, which IPOPT
   does not set; KEEP(197) = 1, the amalgamation of small fronts, is 5.8.2's default and off in
   5.5.1), --label text (copied into each line).
*/
#define _GNU_SOURCE
#include <dlfcn.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include <dmumps_c.h>

#define JOB_INIT -1
#define JOB_END -2
#define USE_COMM_WORLD -987654
#define ICNTL(k) icntl[(k)-1]
#define CNTL(k) cntl[(k)-1]
#define INFOG(k) infog[(k)-1]
#define RINFOG(k) rinfog[(k)-1]

typedef struct {
  int n;
  long long nnz;
  int* irn;
  int* jcn;
  double* a;
} Matrix;

static double cpu_now(void) {
  struct timespec ts;
  clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &ts);
  return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

static double wall_now(void) {
  struct timespec ts;
  clock_gettime(CLOCK_MONOTONIC, &ts);
  return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

static int cmp_double(const void* x, const void* y) {
  const double a = *(const double*)x, b = *(const double*)y;
  return (a > b) - (a < b);
}

static double median(double* v, int n) {
  qsort(v, (size_t)n, sizeof *v, cmp_double);
  return n % 2 ? v[n / 2] : 0.5 * (v[n / 2 - 1] + v[n / 2]);
}

static int read_matrix(const char* path, Matrix* m) {
  FILE* f = fopen(path, "r");
  if (!f) {
    fprintf(stderr, "kkt_mumps: cannot open %s\n", path);
    return 0;
  }
  char line[4096];
  int header = 0, symmetric = 0;
  while (fgets(line, sizeof line, f)) {
    if (!header) {
      header = 1;
      if (strncmp(line, "%%MatrixMarket matrix coordinate real", 37) != 0) {
        fprintf(stderr, "kkt_mumps: %s is not a real coordinate Matrix Market file\n", path);
        fclose(f);
        return 0;
      }
      symmetric = strstr(line, "symmetric") != NULL;
      continue;
    }
    if (line[0] != '%') break;
  }
  if (!symmetric) {
    fprintf(stderr, "kkt_mumps: %s is not symmetric\n", path);
    fclose(f);
    return 0;
  }
  int rows = 0, cols = 0;
  if (sscanf(line, "%d %d %lld", &rows, &cols, &m->nnz) != 3 || rows != cols || rows <= 0 ||
      m->nnz <= 0) {
    fprintf(stderr, "kkt_mumps: %s: bad size line\n", path);
    fclose(f);
    return 0;
  }
  m->n = rows;
  m->irn = malloc((size_t)m->nnz * sizeof(int));
  m->jcn = malloc((size_t)m->nnz * sizeof(int));
  m->a = malloc((size_t)m->nnz * sizeof(double));
  for (long long e = 0; e < m->nnz; ++e) {
    if (fscanf(f, "%d %d %lf", &m->irn[e], &m->jcn[e], &m->a[e]) != 3 || m->irn[e] < 1 ||
        m->irn[e] > m->n || m->jcn[e] < 1 || m->jcn[e] > m->n) {
      fprintf(stderr, "kkt_mumps: %s: bad entry %lld\n", path, e + 1);
      fclose(f);
      return 0;
    }
  }
  fclose(f);
  return 1;
}

static const char* ordering_name(int k) {
  switch (k) {
    case 0:
      return "AMD";
    case 1:
      return "given";
    case 2:
      return "AMF";
    case 3:
      return "SCOTCH";
    case 4:
      return "PORD";
    case 5:
      return "METIS";
    case 6:
      return "QAMD";
    case 7:
      return "automatic";
    default:
      return "?";
  }
}

static void setup(DMUMPS_STRUC_C* id, const Matrix* m, int ordering, double pivtol, int scaling,
                  int permuting, int mem_percent) {
  id->ICNTL(1) = 6;
  id->ICNTL(2) = 0;
  id->ICNTL(3) = 0;
  id->ICNTL(4) = 0;
  id->ICNTL(6) = permuting;
  id->ICNTL(7) = ordering;
  id->ICNTL(8) = scaling;
  id->ICNTL(10) = 0;
  id->ICNTL(13) = 1;
  id->ICNTL(14) = mem_percent;
  id->CNTL(1) = pivtol;
  id->n = m->n;
  id->nnz = m->nnz;
  id->irn = m->irn;
  id->jcn = m->jcn;
  id->a = m->a;
}

int main(int argc, char** argv) {
  int reps = 200;
  int phase_reps[3] = {0, 0, 0};  // 0: --reps
  char orderings[64] = "0,2,3,4,5,6,7";
  double pivtol = 1e-6;
  int scaling = 77, permuting = 7, mem_percent = 1000;
  const char* label = "";
  int keep_index[16], keep_value[16], n_keep = 0;
  int first_file = argc;
  for (int i = 1; i < argc; ++i) {
    if (!strcmp(argv[i], "--reps") && i + 1 < argc) {
      reps = atoi(argv[++i]);
    } else if (!strcmp(argv[i], "--phase-reps") && i + 1 < argc) {
      if (sscanf(argv[++i], "%d,%d,%d", &phase_reps[0], &phase_reps[1], &phase_reps[2]) != 3) {
        fprintf(stderr, "kkt_mumps: --phase-reps wants three counts a,f,s\n");
        return 2;
      }
    } else if (!strcmp(argv[i], "--orderings") && i + 1 < argc) {
      snprintf(orderings, sizeof orderings, "%s", argv[++i]);
    } else if (!strcmp(argv[i], "--pivtol") && i + 1 < argc) {
      pivtol = atof(argv[++i]);
    } else if (!strcmp(argv[i], "--scaling") && i + 1 < argc) {
      scaling = atoi(argv[++i]);
    } else if (!strcmp(argv[i], "--permuting-scaling") && i + 1 < argc) {
      permuting = atoi(argv[++i]);
    } else if (!strcmp(argv[i], "--mem-percent") && i + 1 < argc) {
      mem_percent = atoi(argv[++i]);
    } else if (!strcmp(argv[i], "--keep") && i + 1 < argc) {
      if (n_keep == 16 ||
          sscanf(argv[++i], "%d=%d", &keep_index[n_keep], &keep_value[n_keep]) != 2 ||
          keep_index[n_keep] < 1 || keep_index[n_keep] > 500) {
        fprintf(stderr, "kkt_mumps: --keep wants k=v with 1 <= k <= 500 (at most 16)\n");
        return 2;
      }
      ++n_keep;
    } else if (!strcmp(argv[i], "--label") && i + 1 < argc) {
      label = argv[++i];
    } else if (argv[i][0] == '-') {
      fprintf(stderr, "kkt_mumps: unknown flag %s\n", argv[i]);
      return 2;
    } else {
      first_file = i;
      break;
    }
  }
  if (first_file >= argc || reps < 1) {
    fprintf(stderr,
            "usage: kkt_mumps [--reps N] [--orderings 0,2,...] [--pivtol x] "
            "[--scaling s] [--permuting-scaling p] [--mem-percent m] [--keep k=v] [--label text] "
            "file.mtx...\n");
    return 2;
  }
  Dl_info info;
  const char* library = dladdr((void*)&dmumps_c, &info) && info.dli_fname ? info.dli_fname : "?";
  int max_reps = reps;
  for (int p = 0; p < 3; ++p) {
    if (phase_reps[p] <= 0) phase_reps[p] = reps;
    if (phase_reps[p] > max_reps) max_reps = phase_reps[p];
  }
  double* t_cpu = malloc((size_t)max_reps * sizeof(double));
  double* t_wall = malloc((size_t)max_reps * sizeof(double));
  for (int fi = first_file; fi < argc; ++fi) {
    Matrix m;
    if (!read_matrix(argv[fi], &m)) return 1;
    double* rhs = malloc((size_t)m.n * sizeof(double));
    double* ax = malloc((size_t)m.n * sizeof(double));
    char list[64];
    snprintf(list, sizeof list, "%s", orderings);
    for (char* tok = strtok(list, ","); tok; tok = strtok(NULL, ",")) {
      const int ordering = atoi(tok);
      DMUMPS_STRUC_C id;
      memset(&id, 0, sizeof id);
      id.job = JOB_INIT;
      id.par = 1;
      id.sym = 2;
      id.comm_fortran = USE_COMM_WORLD;
      dmumps_c(&id);
      setup(&id, &m, ordering, pivtol, scaling, permuting, mem_percent);
      for (int k = 0; k < n_keep; ++k) id.keep[keep_index[k] - 1] = keep_value[k];
      double phase_cpu[3], phase_wall[3];
      int status = 0;
      for (int phase = 1; phase <= 3 && status >= 0; ++phase) {
        const int n_reps = phase_reps[phase - 1];
        for (int r = 0; r < n_reps; ++r) {
          if (phase == 3) {
            for (int i = 0; i < m.n; ++i) rhs[i] = 1.0;
            id.rhs = rhs;
            id.nrhs = 1;
            id.lrhs = m.n;
          }
          id.job = phase;
          const double c0 = cpu_now(), w0 = wall_now();
          dmumps_c(&id);
          t_cpu[r] = cpu_now() - c0;
          t_wall[r] = wall_now() - w0;
          if (id.INFOG(1) < 0) {
            status = id.INFOG(1);
            break;
          }
        }
        phase_cpu[phase - 1] = status < 0 ? NAN : 1e3 * median(t_cpu, n_reps);
        phase_wall[phase - 1] = status < 0 ? NAN : 1e3 * median(t_wall, n_reps);
      }
      double residual = NAN;
      if (status >= 0) {
        for (int i = 0; i < m.n; ++i) ax[i] = 0.0;
        for (long long e = 0; e < m.nnz; ++e) {
          const int i = m.irn[e] - 1, j = m.jcn[e] - 1;
          ax[i] += m.a[e] * rhs[j];
          if (i != j) ax[j] += m.a[e] * rhs[i];
        }
        residual = 0.0;
        for (int i = 0; i < m.n; ++i) residual = fmax(residual, fabs(ax[i] - 1.0));
      }
      const int used = id.INFOG(7);
      const int available = ordering == 7 || used == ordering;
      printf(
          "{\"library\": \"%s\", \"mumps_version\": \"%s\", \"label\": \"%s\", "
          "\"matrix\": \"%s\", \"n\": %d, \"nnz\": %lld, \"ordering\": %d, "
          "\"ordering_name\": \"%s\", \"available\": %s, \"ordering_used\": %d, "
          "\"ordering_used_name\": \"%s\", \"pivtol\": %g, \"scaling\": %d, "
          "\"permuting_scaling\": %d, \"mem_percent\": %d, \"keep197\": %d, \"reps\": %d, "
          "\"status\": %d, "
          "\"analysis_ms\": %.4f, \"factorization_ms\": %.4f, \"solve_ms\": %.4f, "
          "\"analysis_wall_ms\": %.4f, \"factorization_wall_ms\": %.4f, "
          "\"solve_wall_ms\": %.4f, \"factor_entries_estimated\": %d, "
          "\"factor_entries\": %d, \"factor_integers\": %d, \"factor_entries_effective\": %d, "
          "\"flops_estimated\": %.6g, \"flops\": %.6g, \"negative_pivots\": %d, "
          "\"delayed_pivots\": %d, \"tree_nodes\": %d, \"max_front\": %d, "
          "\"permuting_scaling_used\": %d, "
          "\"compressed_ordering_used\": %d, \"scaling_used\": %d, \"residual\": %.3g}\n",
          library, MUMPS_VERSION, label, argv[fi], m.n, m.nnz, ordering, ordering_name(ordering),
          available ? "true" : "false", used, ordering_name(used), pivtol, scaling, permuting,
          mem_percent, id.keep[196], reps, status, phase_cpu[0], phase_cpu[1], phase_cpu[2],
          phase_wall[0], phase_wall[1], phase_wall[2], id.INFOG(3), id.INFOG(9), id.INFOG(10),
          id.INFOG(29), id.RINFOG(1), id.RINFOG(3), id.INFOG(12), id.INFOG(13), id.INFOG(6),
          id.INFOG(5), id.INFOG(23), id.INFOG(24), id.INFOG(33), residual);
      fflush(stdout);
      id.job = JOB_END;
      dmumps_c(&id);
    }
    free(rhs);
    free(ax);
    free(m.irn);
    free(m.jcn);
    free(m.a);
  }
  free(t_cpu);
  free(t_wall);
  return 0;
}
