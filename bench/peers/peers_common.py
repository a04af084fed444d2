"""What every comparison of scripts/peers shares: the machine's description, running bflow's
problem program (bench/peer_problems.cc) and reading IPOPT's logs, the rows' distances and
ratios, markdown tables and the generated sections of docs/peers.md."""
import json
import os
import platform
import re
import subprocess
import sys
import time

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
DOCS = os.path.join(ROOT, "docs")
PEERS_MD = os.path.join(DOCS, "peers.md")

# One thread for every BLAS, so that process CPU time is the work of one core for each tool.
SINGLE_THREAD = {"OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}


def log(message):
    print(message, file=sys.stderr, flush=True)


def run_json(command, timeout=None, env=None):
    """Runs a program that prints one JSON object; on failure a row with status "error" and
    the program's last line of stderr."""
    full_env = dict(os.environ)
    full_env.update(SINGLE_THREAD)
    if env:
        full_env.update(env)
    try:
        done = subprocess.run(command, capture_output=True, text=True, timeout=timeout,
                              env=full_env, check=False)
    except subprocess.TimeoutExpired:
        return {"status": "error", "message": f"timed out after {timeout} s"}
    if done.returncode != 0 or not done.stdout.strip():
        lines = [l for l in done.stderr.strip().splitlines() if l.strip()]
        return {"status": "error",
                "message": f"exit code {done.returncode}: " + (lines[-1] if lines else "")}
    return json.loads(done.stdout.strip().splitlines()[-1])


def _first(path, pattern, cast=str):
    with open(path, errors="replace") as f:
        for line in f:
            m = re.search(pattern, line)
            if m:
                return cast(m.group(1))
    return None


def read_ipopt_log(path):
    """The fields bench/ipopt_flags.h reads from an IPOPT log, for a peer's IPOPT: the first
    NLP's problem statistics (as IPOPT sees the NLP) and, summed over every NLP, the CPU time
    (user + sys) of the algorithm, the function and derivative evaluations and the KKT
    factorisations (the linear solves less back-solves, symbolic factorisation, scaling and
    structure conversion, as for IPOPT 3.11, whose MUMPS interface leaves the factorisation
    timer at 0), and the number of MUMPS factorisations."""
    out = {"variables": None, "equalities": None, "inequalities": None,
           "jacobian_nonzeros": None, "hessian_nonzeros": None, "ipopt_cpu_s": 0.0,
           "functions_cpu_s": 0.0, "hessian_cpu_s": 0.0, "factorization_cpu_s": 0.0,
           "back_solve_cpu_s": 0.0,
           "factorization_timer_cpu_s": 0.0, "factorizations": 0, "trial_factorizations": 0,
           "version": None}
    if not path or not os.path.exists(path):
        return out
    counts = {"Total number of variables": "variables",
              "Total number of equality constraints": "equalities",
              "Total number of inequality constraints": "inequalities",
              "Number of nonzeros in Lagrangian Hessian": "hessian_nonzeros"}
    jac = {}
    sums = {"OverallAlgorithm": 0.0, "StdAugSystemSolverMultiSolve": 0.0,
            "LinearSystemBackSolve": 0.0, "LinearSystemSymbolicFactorization": 0.0,
            "LinearSystemScaling": 0.0, "LinearSystemStructureConverter": 0.0,
            "LinearSystemFactorization": 0.0, "Function Evaluations": 0.0,
            "Lagrangian Hessian": 0.0}
    timing = re.compile(r"^\s*([A-Za-z ]+?)\.+:\s*([0-9.eE+-]+) \(sys:\s*([0-9.eE+-]+)")
    with open(path, errors="replace") as f:
        for line in f:
            s = line.strip()
            m = re.match(r"This is Ipopt version ([^,]+), running with linear solver (.+)\.", s)
            if m and out["version"] is None:
                out["version"] = f"IPOPT {m.group(1)}, {m.group(2)}"
            for text, key in counts.items():
                if s.startswith(text + ".") and out[key] is None:
                    out[key] = int(s.split(":")[1])
            for kind in ("equality", "inequality"):
                if s.startswith(f"Number of nonzeros in {kind} constraint Jacobian.") \
                        and kind not in jac:
                    jac[kind] = int(s.split(":")[1])
            if s.startswith("Number of trial factorizations performed:"):
                out["trial_factorizations"] += int(s.split(":")[1])
            if s.startswith("Number of doubles for MUMPS to hold factorization"):
                out["factorizations"] += 1
            m = timing.match(line)
            if m and m.group(1) in sums:
                # In the "Function Evaluations" block "Lagrangian Hessian" is a timing line; the
                # problem statistics' "Number of nonzeros in Lagrangian Hessian" is not.
                sums[m.group(1)] += float(m.group(2)) + float(m.group(3))
    if len(jac) == 2:
        out["jacobian_nonzeros"] = jac["equality"] + jac["inequality"]
    out["ipopt_cpu_s"] = sums["OverallAlgorithm"]
    out["functions_cpu_s"] = sums["Function Evaluations"]
    out["hessian_cpu_s"] = sums["Lagrangian Hessian"]
    out["factorization_cpu_s"] = (sums["StdAugSystemSolverMultiSolve"]
                                  - sums["LinearSystemBackSolve"]
                                  - sums["LinearSystemSymbolicFactorization"]
                                  - sums["LinearSystemScaling"]
                                  - sums["LinearSystemStructureConverter"])
    out["back_solve_cpu_s"] = sums["LinearSystemBackSolve"]
    out["factorization_timer_cpu_s"] = sums["LinearSystemFactorization"]
    return out


def _command_first_line(command):
    try:
        done = subprocess.run(command, capture_output=True, text=True, check=False)
        lines = (done.stdout or done.stderr).strip().splitlines()
        return lines[0] if lines else None
    except OSError:
        return None


def machine(build_dir):
    """What the numbers were measured on."""
    info = {}
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith("model name"):
                    info["cpu"] = line.split(":", 1)[1].strip()
                    break
    except OSError:
        pass
    info["cores"] = os.cpu_count()
    try:
        with open("/proc/meminfo") as f:
            kb = int(f.readline().split()[1])
        info["memory_gib"] = round(kb / 2**20, 1)
    except (OSError, ValueError, IndexError):
        pass
    try:
        with open("/etc/os-release") as f:
            for line in f:
                if line.startswith("PRETTY_NAME="):
                    info["os"] = line.split("=", 1)[1].strip().strip('"')
    except OSError:
        pass
    info["kernel"] = platform.release()
    info["python"] = platform.python_version()
    compiler = None
    cache = os.path.join(build_dir, "CMakeCache.txt")
    if os.path.exists(cache):
        path = _first(cache, r"^CMAKE_CXX_COMPILER:\w+=(.*)$")
        build_type = _first(cache, r"^CMAKE_BUILD_TYPE:\w+=(.*)$")
        if path:
            compiler = _command_first_line([path, "--version"])
        info["build_type"] = build_type
    info["compiler"] = compiler
    # The solver stack the build links (cmake/BflowIpopt.cmake records it in the cache).
    info["bflow_ipopt"] = None
    info["bflow_mumps"] = None
    if os.path.exists(cache):
        info["bflow_ipopt"] = _first(cache, r"^BFLOW_IPOPT_FOUND_VERSION:\w+=(.*)$")
        mumps = _first(cache, r"^BFLOW_MUMPS_FOUND_VERSION:\w+=(.*)$")
        info["bflow_mumps"] = f"MUMPS {mumps}" if mumps else None
        info["bflow_ipopt_prefix"] = _first(cache, r"^BFLOW_IPOPT_RESOLVED:\w+=(.*)$")
    info["git"] = _command_first_line(["git", "-C", ROOT, "describe", "--always", "--dirty"])
    info["date"] = time.strftime("%Y-%m-%d %H:%M %Z")
    info["load_average_before"] = os.getloadavg()[0]
    info["threads"] = "OMP_NUM_THREADS=OPENBLAS_NUM_THREADS=1, every run in its own process"
    return info


def max_distance(a, b):
    """max over the stage boundaries k and states i of |a[k][i] - b[k][i]|, or None."""
    if not a or not b or len(a) != len(b):
        return None
    return max(abs(x - y) for ra, rb in zip(a, b) for x, y in zip(ra, rb))


def median(values):
    v = sorted(x for x in values if x is not None)
    if not v:
        return None
    n = len(v)
    return v[n // 2] if n % 2 else 0.5 * (v[n // 2 - 1] + v[n // 2])


def fmt(x, digits=3):
    """A number for a markdown table: 3 significant digits, '—' for none."""
    if x is None:
        return "—"
    if isinstance(x, str):
        return x
    if x == 0:
        return "0"
    if abs(x) >= 1e4 or abs(x) < 1e-3:
        return f"{x:.{digits - 1}e}"
    return f"{x:.{digits}g}"


def table(header, rows, align=None):
    align = align or ["---"] * len(header)
    lines = ["| " + " | ".join(header) + " |", "| " + " | ".join(align) + " |"]
    lines += ["| " + " | ".join(str(c) for c in r) + " |" for r in rows]
    return "\n".join(lines)


def begin_marker(name):
    return f"<!-- peers:{name}:begin (generated by scripts/peers {name}; edits are overwritten) -->"


def end_marker(name):
    return f"<!-- peers:{name}:end -->"


def replace_section(name, text, path=PEERS_MD):
    """Puts `text` between the comparison's markers in docs/peers.md (appended with its markers
    when they are not there yet); the prose around them is left alone."""
    with open(path) as f:
        doc = f.read()
    begin = f"<!-- peers:{name}:begin"
    end = end_marker(name)
    block = begin_marker(name) + "\n" + text.rstrip() + "\n" + end
    if begin in doc and end in doc:
        start = doc.index(begin)
        stop = doc.index(end) + len(end)
        doc = doc[:start] + block + doc[stop:]
    else:
        doc = doc.rstrip() + "\n\n" + block + "\n"
    with open(path, "w") as f:
        f.write(doc)
