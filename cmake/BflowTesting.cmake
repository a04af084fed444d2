# Test labels and their budgets (included from the root CMakeLists.txt when tests are built).
#
# Every test carries one label, what it tests: a component (core, ad, integrators, fesd, ocp,
# orbits, sweep, cli) or docs, fuzz, install, mpi, examples, bench, style (the format check). A label's budget is the
# TIMEOUT of each of its tests in seconds, for an optimised build; a sanitizer build multiplies
# it by BFLOW_TEST_BUDGET_SCALE. Each budget is at least ten times the slowest test of its label
# as measured in both passes (docs/testing.md), so that a slower machine passes; a test that
# overruns it (a hang) fails instead of holding the run. `ctest -L ocp` runs one label; ctest's "Label Time Summary" gives each
# label's time.
#
# A label's COST orders the first run of a fresh build tree, before ctest has measured anything:
# the labels whose tests take longest start first, so that they do not end the run alone.
set(BFLOW_TEST_BUDGET_core 60)
set(BFLOW_TEST_BUDGET_ad 60)
set(BFLOW_TEST_BUDGET_integrators 120)
set(BFLOW_TEST_BUDGET_fesd 120)
set(BFLOW_TEST_BUDGET_ocp 400)
set(BFLOW_TEST_BUDGET_orbits 120)
set(BFLOW_TEST_BUDGET_sweep 120)
set(BFLOW_TEST_BUDGET_cli 300)
set(BFLOW_TEST_BUDGET_docs 120)
set(BFLOW_TEST_BUDGET_fuzz 300)
set(BFLOW_TEST_BUDGET_install 600)
set(BFLOW_TEST_BUDGET_mpi 180)
set(BFLOW_TEST_BUDGET_examples 120)
set(BFLOW_TEST_BUDGET_bench 120)
set(BFLOW_TEST_BUDGET_style 120)
set(BFLOW_TEST_COST_ocp 100)
set(BFLOW_TEST_COST_install 50)
set(BFLOW_TEST_COST_mpi 20)
set(BFLOW_TEST_COST_cli 10)
set(BFLOW_TEST_COST_fesd 5)

if(BFLOW_SANITIZE OR BFLOW_FUZZ)
  set(BFLOW_TEST_BUDGET_SCALE 4 CACHE STRING "Test budgets' factor in this build")
else()
  set(BFLOW_TEST_BUDGET_SCALE 1 CACHE STRING "Test budgets' factor in this build")
endif()

# bflow_test_properties(<label> <var>): in <var>, the test properties of the label (LABELS,
# TIMEOUT, COST) as a list of property-value pairs for set_tests_properties.
function(bflow_test_properties label var)
  if(NOT DEFINED BFLOW_TEST_BUDGET_${label})
    message(FATAL_ERROR "bflow_test_properties: no budget for the test label \"${label}\"")
  endif()
  math(EXPR timeout "${BFLOW_TEST_BUDGET_${label}} * ${BFLOW_TEST_BUDGET_SCALE}")
  set(cost 0)
  if(DEFINED BFLOW_TEST_COST_${label})
    set(cost ${BFLOW_TEST_COST_${label}})
  endif()
  set(${var} LABELS ${label} TIMEOUT ${timeout} COST ${cost} PARENT_SCOPE)
endfunction()

# bflow_label_tests(<label>): labels every test of the current directory that has no label yet
# (add_test calls) and gives it the label's budget, unless the test sets a TIMEOUT of its own
# (a shorter one, where a hang is what the test is about).
function(bflow_label_tests label)
  bflow_test_properties(${label} properties)
  get_property(tests DIRECTORY PROPERTY TESTS)
  foreach(test IN LISTS tests)
    get_test_property(${test} LABELS labels)
    if(labels)
      continue()
    endif()
    get_test_property(${test} TIMEOUT timeout)
    if(timeout)
      set_tests_properties(${test} PROPERTIES ${properties} TIMEOUT ${timeout})
    else()
      set_tests_properties(${test} PROPERTIES ${properties})
    endif()
  endforeach()
endfunction()
