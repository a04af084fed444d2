# Runs a program and checks its exit code and output (ctest: cmake -D... -P run_and_match.cmake).
# Unlike ctest's PASS_REGULAR_EXPRESSION, which decides on the output alone and ignores the exit
# status, this fails when either is wrong.
#   PROGRAM          the executable
#   ARGS             optional: its arguments, separated by '|'
#   STDIN            optional: file fed to its standard input
#   STDOUT_FILE      optional: file its standard output goes to instead of being captured
#                    (/dev/full: every write fails); STDOUT_REGEX then sees an empty stdout
#   EXPECTED_CODE    optional: the exit code that must be returned (default 0)
#   EXPECTED_STDERR  optional: stderr must be exactly this line (plus its newline)
#   STDERR_REGEX     optional: stderr must match this regular expression
#   STDOUT_REGEX     optional: stdout must match this regular expression
# The program's stdout and stderr are printed either way, so they show in the test log.
if(NOT DEFINED PROGRAM)
  message(FATAL_ERROR "run_and_match.cmake: PROGRAM is not set")
endif()
if(NOT DEFINED EXPECTED_CODE)
  set(EXPECTED_CODE 0)
endif()
string(REPLACE "|" ";" arguments "${ARGS}")
if(DEFINED STDIN)
  set(input INPUT_FILE "${STDIN}")
endif()
set(out "")
if(DEFINED STDOUT_FILE)
  set(output OUTPUT_FILE "${STDOUT_FILE}")
else()
  set(output OUTPUT_VARIABLE out)
endif()
execute_process(COMMAND "${PROGRAM}" ${arguments} ${input} ${output}
                RESULT_VARIABLE code ERROR_VARIABLE err)
list(JOIN arguments " " joined)
string(STRIP "${PROGRAM} ${joined}" command)
message("${command}\n-- stdout --\n${out}-- stderr --\n${err}-- exit code ${code}")
if(NOT code STREQUAL "${EXPECTED_CODE}")
  message(FATAL_ERROR "${command}: exit code ${code}, expected ${EXPECTED_CODE}")
endif()
if(DEFINED EXPECTED_STDERR AND NOT err STREQUAL "${EXPECTED_STDERR}\n")
  message(FATAL_ERROR "${command}: stderr is\n[${err}]\nexpected exactly one line\n"
                      "[${EXPECTED_STDERR}]")
endif()
if(DEFINED STDERR_REGEX AND NOT err MATCHES "${STDERR_REGEX}")
  message(FATAL_ERROR "${command}: stderr does not match [${STDERR_REGEX}]")
endif()
if(DEFINED STDOUT_REGEX AND NOT out MATCHES "${STDOUT_REGEX}")
  message(FATAL_ERROR "${command}: stdout does not match [${STDOUT_REGEX}]")
endif()
