# Runs `bflow demo --output OUTPUT_DIR` and checks that it drew a non-empty PNG whose path is the
# last line printed (ctest: cmake -P).
#   BFLOW       the executable
#   OUTPUT_DIR  the directory for the demo's files (emptied first)
file(REMOVE_RECURSE "${OUTPUT_DIR}")
execute_process(COMMAND "${BFLOW}" demo --output "${OUTPUT_DIR}"
                RESULT_VARIABLE code OUTPUT_VARIABLE out ERROR_VARIABLE err)
if(NOT code EQUAL 0)
  message(FATAL_ERROR "bflow demo: exit code ${code}\nstdout: ${out}\nstderr: ${err}")
endif()
set(png "${OUTPUT_DIR}/demo_circle.png")
if(NOT EXISTS "${png}")
  message(FATAL_ERROR "bflow demo did not write ${png}\nstdout: ${out}")
endif()
file(SIZE "${png}" size)
file(READ "${png}" magic LIMIT 8 HEX)
if(size EQUAL 0 OR NOT magic STREQUAL "89504e470d0a1a0a")
  message(FATAL_ERROR "${png} is not a PNG (size ${size}, first bytes ${magic})")
endif()
if(NOT out MATCHES "All checks passed\\.\n" OR NOT out MATCHES "demo_circle\\.png\n$")
  message(FATAL_ERROR "bflow demo: unexpected output:\n${out}")
endif()
message(STATUS "${png}: ${size} bytes")
