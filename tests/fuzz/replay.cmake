# The seed corpus of every fuzz harness replayed as ordinary tests (included from
# tests/CMakeLists.txt): <target>_replay is the harness linked with replay_main.cc instead of
# libFuzzer, and the test fuzz_replay_<target> (label fuzz) runs it on tests/fuzz/corpus/<target>.
# A contract violation aborts, so the test fails in any build, GCC or clang, with or without the
# sanitizers.
find_package(nlohmann_json 3.2 REQUIRED)
include(${CMAKE_CURRENT_LIST_DIR}/targets.cmake)

foreach(target IN LISTS BFLOW_FUZZ_TARGETS)
  add_executable(${target}_replay ${CMAKE_CURRENT_LIST_DIR}/${target}_fuzz.cc
                                  ${CMAKE_CURRENT_LIST_DIR}/replay_main.cc)
  set_target_properties(${target}_replay PROPERTIES RUNTIME_OUTPUT_DIRECTORY
                                                    ${CMAKE_CURRENT_BINARY_DIR}/fuzz)
  target_include_directories(${target}_replay PRIVATE ${PROJECT_SOURCE_DIR}/tests)
  target_link_libraries(${target}_replay PRIVATE bflow_cli nlohmann_json::nlohmann_json
                        bflow_warnings)
  add_test(NAME fuzz_replay_${target}
           COMMAND ${target}_replay ${CMAKE_CURRENT_LIST_DIR}/corpus/${target})
  set_tests_properties(fuzz_replay_${target} PROPERTIES LABELS fuzz TIMEOUT 300)
endforeach()
