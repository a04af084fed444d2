# The same sweep in one process and under `mpirun --oversubscribe -np RANKS`: the outputs must be
# identical, byte for byte. -DBFLOW=<bflow> -DMPIRUN=<mpirun> -DRANKS=<K> -DWORK_DIR=<dir>
# -DFORMAT=<jsonl|csv>
file(MAKE_DIRECTORY ${WORK_DIR})
set(args sweep --scene biped --vary 2=-0.01:0.01:9 --vary 5=-0.1:0.1:7 --dx 0,0,1,0,0,0
         --format ${FORMAT} --quiet --threads 1)
execute_process(COMMAND ${BFLOW} ${args} --output ${WORK_DIR}/single.${FORMAT}
                RESULT_VARIABLE code ERROR_VARIABLE err)
if(NOT code EQUAL 0)
  message(FATAL_ERROR "the single-process sweep failed (${code}): ${err}")
endif()
execute_process(COMMAND ${MPIRUN} --oversubscribe -np ${RANKS} ${BFLOW} ${args}
                        --output ${WORK_DIR}/ranks${RANKS}.${FORMAT}
                RESULT_VARIABLE code ERROR_VARIABLE err TIMEOUT 120)
if(NOT code EQUAL 0)
  message(FATAL_ERROR "mpirun -np ${RANKS} failed (${code}): ${err}")
endif()
file(READ ${WORK_DIR}/single.${FORMAT} single)
file(READ ${WORK_DIR}/ranks${RANKS}.${FORMAT} ranked)
string(LENGTH "${single}" length)
if(length LESS 1000)
  message(FATAL_ERROR "the single-process output is too short (${length} bytes)")
endif()
if(NOT single STREQUAL ranked)
  message(FATAL_ERROR "mpirun -np ${RANKS}: the output differs from the single process's")
endif()
message("mpirun -np ${RANKS} (${FORMAT}): ${length} bytes, identical to the single process's")
