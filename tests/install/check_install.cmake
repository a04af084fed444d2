# cmake -DBUILD_DIR=... -DSOURCE_DIR=... -DWORK_DIR=... -DGENERATOR=... -DCERES_INCLUDE_DIR=...
#       -P check_install.cmake
# Installs BUILD_DIR into one scratch prefix and checks the CMake package from separate projects
# (SOURCE_DIR/consumer*):
#   targets      no exported target lists an include directory twice;
#   unknown      find_package(bflow COMPONENTS core bogus) fails and names the component;
#   core         COMPONENTS core configures, builds and runs with SUNDIALS, pkg-config (IPOPT)
#                and the other components' targets files out of reach;
#   ad           COMPONENTS ad compiles Jet code with the ceres include directory that the
#                imported target bflow::ad carries (a copy, to tell it from /usr/include);
#   fesd         COMPONENTS fesd runs fesd_simulate with SUNDIALS not findable and the other
#                components' targets files away;
#   full         no COMPONENTS, bflow::bflow: jump map, CVODES and FESD (IPOPT) linked and run.
# Fails unless every step succeeds and each consumer prints its numbers.
file(REMOVE_RECURSE ${WORK_DIR})
set(prefix ${WORK_DIR}/prefix)
set(package_dir ${prefix}/lib/cmake/bflow)

function(run)
  execute_process(COMMAND ${ARGN} RESULT_VARIABLE code OUTPUT_VARIABLE out ERROR_VARIABLE err)
  if(NOT code EQUAL 0)
    message(FATAL_ERROR "failed (${code}): ${ARGN}\n${out}\n${err}")
  endif()
endfunction()

# consumer(<name> <source dir> <expected stdout regex> [extra configure arguments...])
function(consumer name source regex)
  set(build ${WORK_DIR}/${name})
  set(launcher "")
  if(PKG_CONFIG_LIBDIR)
    set(launcher ${CMAKE_COMMAND} -E env PKG_CONFIG_LIBDIR=${PKG_CONFIG_LIBDIR})
  endif()
  run(${launcher} ${CMAKE_COMMAND} -S ${source} -B ${build} -G ${GENERATOR} -DCMAKE_PREFIX_PATH=${prefix}
      -DCMAKE_BUILD_TYPE=Release -DCMAKE_EXPORT_COMPILE_COMMANDS=ON ${ARGN})
  run(${CMAKE_COMMAND} --build ${build})
  execute_process(COMMAND ${build}/app RESULT_VARIABLE code OUTPUT_VARIABLE out)
  message("${name}: ${out}")
  if(NOT code EQUAL 0)
    message(FATAL_ERROR "${name}: the consumer exited with ${code}")
  endif()
  if(NOT out MATCHES "${regex}")
    message(FATAL_ERROR "${name}: the consumer's output does not match [${regex}]")
  endif()
endfunction()

run(${CMAKE_COMMAND} --install ${BUILD_DIR} --prefix ${prefix})

# targets: one file per component and the umbrella; no duplicated include directory.
foreach(set IN ITEMS bflowCoreTargets bflowAdTargets bflowIntegratorsTargets bflowFesdTargets
                     bflowOcpTargets bflowSweepTargets bflowTargets)
  if(NOT EXISTS ${package_dir}/${set}.cmake)
    message(FATAL_ERROR "targets: ${package_dir}/${set}.cmake was not installed")
  endif()
  # Semicolons separate the directories: kept out of CMake's list splitting until each value.
  file(READ ${package_dir}/${set}.cmake text)
  string(REPLACE ";" "<sep>" text "${text}")
  string(REGEX MATCHALL "INTERFACE_INCLUDE_DIRECTORIES \"[^\"]*\"" values "${text}")
  foreach(value IN LISTS values)
    string(REGEX REPLACE "^INTERFACE_INCLUDE_DIRECTORIES \"(.*)\"$" "\\1" dirs "${value}")
    string(REPLACE "<sep>" ";" dirs "${dirs}")
    set(unique ${dirs})
    list(REMOVE_DUPLICATES unique)
    if(NOT unique STREQUAL dirs)
      message(FATAL_ERROR "targets: ${set}.cmake lists an include directory twice: ${dirs}")
    endif()
  endforeach()
endforeach()
message("targets: no duplicated include directory")

# unknown: a component that does not exist.
file(WRITE ${WORK_DIR}/unknown_source/CMakeLists.txt
     "cmake_minimum_required(VERSION 3.18)\nproject(app LANGUAGES CXX)\n"
     "find_package(bflow 0.1 REQUIRED COMPONENTS core bogus)\n")
execute_process(COMMAND ${CMAKE_COMMAND} -S ${WORK_DIR}/unknown_source -B ${WORK_DIR}/unknown
                -G ${GENERATOR} -DCMAKE_PREFIX_PATH=${prefix}
                RESULT_VARIABLE code OUTPUT_VARIABLE out ERROR_VARIABLE err)
string(REGEX REPLACE "[ \t\r\n]+" " " err_flat "${err}")
set(expected "unknown component \"bogus\"; the components are core, ad, integrators, fesd, ocp, sweep and orbits")
if(code EQUAL 0 OR NOT err_flat MATCHES "bflow_FOUND to FALSE" OR
   NOT err_flat MATCHES "${expected}")
  message(FATAL_ERROR "unknown: expected a failure with [${expected}], got ${code}:\n${err}")
endif()
message("unknown: refused with \"${expected}\"")

# core: the other targets files moved away and SUNDIALS, pkg-config and IPOPT not findable; a
# package that loaded or searched them fails to configure.
set(hidden bflowAdTargets.cmake bflowIntegratorsTargets.cmake bflowFesdTargets.cmake
           bflowOcpTargets.cmake bflowSweepTargets.cmake bflowTargets.cmake)
foreach(file IN LISTS hidden)
  file(RENAME ${package_dir}/${file} ${package_dir}/${file}.hidden)
endforeach()
set(PKG_CONFIG_LIBDIR ${WORK_DIR}/no-pkg-config)
consumer(core ${SOURCE_DIR}/consumer_core "consumer_core: B\\(dx\\) = \\[0.5, 1\\]"
         -DCMAKE_DISABLE_FIND_PACKAGE_SUNDIALS=ON -DCMAKE_DISABLE_FIND_PACKAGE_PkgConfig=ON)
foreach(file IN LISTS hidden)
  file(RENAME ${package_dir}/${file}.hidden ${package_dir}/${file})
endforeach()
unset(PKG_CONFIG_LIBDIR)

# ad: ceres/jet.h from a copy of its directory, which must reach the compile line through
# bflow::ad.
set(jet_dir ${WORK_DIR}/jet_include)
file(COPY ${CERES_INCLUDE_DIR}/ceres DESTINATION ${jet_dir})
consumer(ad ${SOURCE_DIR}/consumer_ad
         "consumer_ad: d\\(x\\^3\\)/dx = 12, J = \\[3, 1; 0.540302, 0\\], B\\(dx\\) = \\[0.5, 1\\]"
         -DBFLOW_CERES_INCLUDE_DIR=${jet_dir})
file(READ ${WORK_DIR}/ad/compile_commands.json commands)
string(FIND "${commands}" "-isystem ${jet_dir} " at)
if(at EQUAL -1)
  message(FATAL_ERROR "ad: the compile line lacks -isystem ${jet_dir}:\n${commands}")
endif()
message("ad: compiled with -isystem ${jet_dir} from bflow::ad")

# fesd: the integrators', the OCP's, the sweep's and the orbits' targets files moved away and
# SUNDIALS not findable; FESD needs IPOPT alone.
set(hidden bflowIntegratorsTargets.cmake bflowOcpTargets.cmake bflowSweepTargets.cmake
           bflowOrbitsTargets.cmake bflowTargets.cmake)
foreach(file IN LISTS hidden)
  file(RENAME ${package_dir}/${file} ${package_dir}/${file}.hidden)
endforeach()
consumer(fesd ${SOURCE_DIR}/consumer_fesd "consumer_fesd: x\\(1\\) = 0.666667, switch at 0.333333"
         -DCMAKE_DISABLE_FIND_PACKAGE_SUNDIALS=ON)
foreach(file IN LISTS hidden)
  file(RENAME ${package_dir}/${file}.hidden ${package_dir}/${file})
endforeach()

# full: everything, as the README shows.
consumer(full ${SOURCE_DIR}/consumer
         "consumer: B\\(dx\\) = \\[0.5, 1\\], cvodes D phi_1\\(dx\\) = \\[0.5, 1\\], fesd x\\(1\\) = 0.666667")
