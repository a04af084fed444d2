# Sweeps in one process and under `mpirun --oversubscribe -np RANKS` write the same bytes:
#  1. the biped over 41 x 41 starts, in chunks of several records (1681 / (16 RANKS) >= 35), and
#     every rank computed samples (the summary line counts them per rank);
#  2. the piecewise-constant field with a row of failed samples (starts on a surface);
#  3. --resume of an output cut in the middle of a record;
#  4. --atlas: the same atlas data.
# -DBFLOW=<bflow> -DMPIRUN=<mpirun> -DRANKS=<K> -DWORK_DIR=<dir> -DFORMAT=<jsonl|csv>
file(REMOVE_RECURSE ${WORK_DIR})
file(MAKE_DIRECTORY ${WORK_DIR})

# Runs the sweep ARGS in one process (into single.*) and under mpirun (into ranks.*), checks
# that both succeed and wrote the same bytes; sets <prefix>_err to mpirun's stderr.
function(compare name)
  set(args ${ARGN})
  execute_process(COMMAND ${BFLOW} ${args} --output ${WORK_DIR}/${name}_single.${FORMAT}
                  RESULT_VARIABLE code ERROR_VARIABLE err TIMEOUT 120)
  if(NOT code EQUAL 0)
    message(FATAL_ERROR "${name}: the single-process sweep failed (${code}): ${err}")
  endif()
  execute_process(COMMAND ${MPIRUN} --oversubscribe -np ${RANKS} ${BFLOW} ${args}
                          --output ${WORK_DIR}/${name}_ranks.${FORMAT}
                  RESULT_VARIABLE code ERROR_VARIABLE err TIMEOUT 120)
  if(NOT code EQUAL 0)
    message(FATAL_ERROR "${name}: mpirun -np ${RANKS} failed (${code}): ${err}")
  endif()
  file(READ ${WORK_DIR}/${name}_single.${FORMAT} single)
  file(READ ${WORK_DIR}/${name}_ranks.${FORMAT} ranked)
  string(LENGTH "${single}" length)
  if(length LESS 1000)
    message(FATAL_ERROR "${name}: the single-process output is too short (${length} bytes)")
  endif()
  if(NOT single STREQUAL ranked)
    message(FATAL_ERROR "${name}: mpirun -np ${RANKS}: the output differs from the single process's")
  endif()
  set(${name}_err "${err}" PARENT_SCOPE)
  set(${name}_single "${single}" PARENT_SCOPE)
  message("${name}: mpirun -np ${RANKS} (${FORMAT}): ${length} bytes, identical to the single process's")
endfunction()

# 1. Chunks of several records; every rank's share.
set(biped sweep --scene biped --vary 2=-0.01:0.01:41 --vary 5=-0.1:0.1:41 --dx 0,0,1,0,0,0
          --rtol 1e-11 --format ${FORMAT} --quiet --threads 1)
compare(biped ${biped})
if(NOT biped_err MATCHES "sweep: 1681 samples, 1681 ok; computed by ranks 0\\.\\.([0-9]+): ([0-9, ]+)\n")
  message(FATAL_ERROR "biped: no per-rank count in: ${biped_err}")
endif()
math(EXPR last "${RANKS} - 1")
if(NOT CMAKE_MATCH_1 EQUAL last)
  message(FATAL_ERROR "biped: counts for ranks 0..${CMAKE_MATCH_1}, expected 0..${last}")
endif()
string(REPLACE ", " ";" counts "${CMAKE_MATCH_2}")
set(total 0)
foreach(count IN LISTS counts)
  if(count EQUAL 0)
    message(FATAL_ERROR "biped: a rank computed no sample: ${CMAKE_MATCH_2}")
  endif()
  math(EXPR total "${total} + ${count}")
endforeach()
if(NOT total EQUAL 1681)
  message(FATAL_ERROR "biped: the ranks computed ${total} samples, expected 1681")
endif()
message("biped: samples per rank ${CMAKE_MATCH_2}")

# 2. Failed samples: x[1] = -0.2 + 0.4 k / 40 is 0 at k = 20, a start on surface 1.
compare(failed sweep --scene pwconst --x0=-0.5,0 --vary 0=-1:-0.1:30 --vary 1=-0.2:0.2:41
        --dx 1,0 --format ${FORMAT} --quiet --threads 1)
if(NOT failed_err MATCHES "sweep: 1230 samples, 1200 ok, 30 rejected;")
  message(FATAL_ERROR "failed: expected 30 rejected samples: ${failed_err}")
endif()

# 3. The biped's output cut 17 bytes into a record halfway, resumed under mpirun.
string(LENGTH "${biped_single}" length)
math(EXPR half "${length} / 2")
string(SUBSTRING "${biped_single}" 0 ${half} head)
string(FIND "${head}" "\n" newline REVERSE)
math(EXPR cut "${newline} + 18")
string(SUBSTRING "${biped_single}" 0 ${cut} head)
file(WRITE ${WORK_DIR}/resumed.${FORMAT} "${head}")
execute_process(COMMAND ${MPIRUN} --oversubscribe -np ${RANKS} ${BFLOW} ${biped}
                        --output ${WORK_DIR}/resumed.${FORMAT} --resume
                RESULT_VARIABLE code ERROR_VARIABLE err TIMEOUT 120)
if(NOT code EQUAL 0)
  message(FATAL_ERROR "resume: mpirun -np ${RANKS} failed (${code}): ${err}")
endif()
file(READ ${WORK_DIR}/resumed.${FORMAT} resumed)
if(NOT resumed STREQUAL biped_single)
  message(FATAL_ERROR "resume: the resumed output differs from the uninterrupted one")
endif()
if(NOT err MATCHES "samples kept from")
  message(FATAL_ERROR "resume: nothing was kept: ${err}")
endif()
message("resume: cut at byte ${cut} of ${length}, resumed under mpirun: identical")

# 4. The atlas: the same data from every rank's samples (the PNG needs gnuplot).
find_program(GNUPLOT gnuplot)
if(GNUPLOT)
  set(atlas sweep --scene pwconst --vary 0=-1:-0.05:21 --vary 1=-1:-0.05:21 --dx 1,0
            --format ${FORMAT} --quiet --threads 1)
  execute_process(COMMAND ${BFLOW} ${atlas} --atlas ${WORK_DIR}/atlas_single.png
                  RESULT_VARIABLE code ERROR_VARIABLE err OUTPUT_QUIET TIMEOUT 120)
  if(NOT code EQUAL 0)
    message(FATAL_ERROR "atlas: the single-process sweep failed (${code}): ${err}")
  endif()
  execute_process(COMMAND ${MPIRUN} --oversubscribe -np ${RANKS} ${BFLOW} ${atlas}
                          --atlas ${WORK_DIR}/atlas_ranks.png
                  RESULT_VARIABLE code ERROR_VARIABLE err OUTPUT_QUIET TIMEOUT 120)
  if(NOT code EQUAL 0)
    message(FATAL_ERROR "atlas: mpirun -np ${RANKS} failed (${code}): ${err}")
  endif()
  file(READ ${WORK_DIR}/atlas_single.dat first)
  file(READ ${WORK_DIR}/atlas_ranks.dat ranked)
  string(LENGTH "${first}" length)
  if(length LESS 4000 OR NOT first STREQUAL ranked)
    message(FATAL_ERROR "atlas: the atlas data under mpirun differs from the single process's")
  endif()
  if(NOT EXISTS ${WORK_DIR}/atlas_ranks.png)
    message(FATAL_ERROR "atlas: mpirun drew no PNG")
  endif()
  message("atlas: identical data (${length} bytes)")
else()
  message("atlas: skipped (no gnuplot)")
endif()
