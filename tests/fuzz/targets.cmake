# The fuzz harnesses, each tests/fuzz/<target>_fuzz.cc with its dictionary <target>.dict and its
# seed corpus corpus/<target>/ (scripts/fuzz has the same list).
set(BFLOW_FUZZ_TARGETS jump flow_args fesd_args ocp_args sweep_args sweep_resume)
