# Runs the bflow command and checks its exit code and output exactly (ctest: cmake -P).
#   BFLOW            the executable
#   ARGS             its arguments, separated by '|'
#   STDIN            optional file fed to its standard input
#   EXPECTED_CODE    the exit code that must be returned
#   EXPECTED_STDERR  optional: stderr must be exactly this line (plus its newline)
#   STDERR_REGEX     optional: stderr must match this regular expression
#   STDOUT_REGEX     optional: stdout must match this regular expression
string(REPLACE "|" ";" arguments "${ARGS}")
if(DEFINED STDIN)
  set(input INPUT_FILE "${STDIN}")
endif()
execute_process(COMMAND "${BFLOW}" ${arguments} ${input}
                RESULT_VARIABLE code OUTPUT_VARIABLE out ERROR_VARIABLE err)
if(NOT code STREQUAL "${EXPECTED_CODE}")
  message(FATAL_ERROR "bflow ${arguments}: exit code ${code}, expected ${EXPECTED_CODE}\n"
                      "stdout: ${out}\nstderr: ${err}")
endif()
if(DEFINED EXPECTED_STDERR AND NOT err STREQUAL "${EXPECTED_STDERR}\n")
  message(FATAL_ERROR "bflow ${arguments}: stderr is\n[${err}]\nexpected exactly one line\n"
                      "[${EXPECTED_STDERR}]")
endif()
if(DEFINED STDERR_REGEX AND NOT err MATCHES "${STDERR_REGEX}")
  message(FATAL_ERROR "bflow ${arguments}: stderr does not match [${STDERR_REGEX}]:\n${err}")
endif()
if(DEFINED STDOUT_REGEX AND NOT out MATCHES "${STDOUT_REGEX}")
  message(FATAL_ERROR "bflow ${arguments}: stdout does not match [${STDOUT_REGEX}]:\n${out}")
endif()
