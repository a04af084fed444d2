# The IPOPT that bflow's FESD and optimal control are built against (docs/ocp.md, "The solver
# stack"), chosen at configure time by BFLOW_IPOPT:
#
#   auto     (default) the prefix scripts/install-deps fills from the pinned casadi 3.8.2 wheel
#            (IPOPT 3.14.19, MUMPS 5.8.2, METIS, SPRAL), else Debian's IPOPT 3.11.9
#   wheel    that prefix, or a configure error saying how to install it
#   system   IPOPT through pkg-config (Debian 12: coinor-libipopt-dev, IPOPT 3.11.9 with MUMPS 5.5.1)
#   <path>   an IPOPT prefix: <path>/lib/libipopt.so.3 (or <path>/libipopt.so.3, as in an installed
#            casadi package) with the headers in <path>/include/coin-or
#
# bflow_find_ipopt() makes the imported target bflow::ipopt (libraries only: the headers are
# given to the two sources that include them, BFLOW_IPOPT_SOURCES_INCLUDE_DIRS, so that every
# other source compiles the same whichever IPOPT is chosen) and sets, in the caller's scope:
#   BFLOW_IPOPT_RESOLVED          the prefix found, or "system"
#   BFLOW_IPOPT_VERSION           e.g. 3.14.19 (IpoptConfig.h)
#   BFLOW_MUMPS_VERSION           e.g. 5.8.2 (dmumps_c.h)
#   BFLOW_IPOPT_INCLUDE_DIRS      IPOPT's and MUMPS's header folders
#   BFLOW_IPOPT_COMPILE_OPTIONS   what a source that includes them is compiled with: the folders as
#                                 system headers (-isystem: their warnings are not bflow's) and
#                                 the definitions pkg-config's IPOPT asks for
#   BFLOW_IPOPT_HAS_SPRAL         IPOPT was built with SPRAL (its library holds SPRAL's SSIDS)
#   BFLOW_MUMPS_INTERPOSER        bflow's dmumps_c is needed: a MUMPS before 5.8, which does not
#                                 amalgamate small fronts by default (fesd/src/mumps_fronts.cc)
# The installed package's bflowConfig.cmake calls it with the prefix the build used.
set(BFLOW_DEFAULT_IPOPT_PREFIX "$ENV{HOME}/.cache/bflow/deps/ipopt-3.14.19")
if(DEFINED ENV{BFLOW_DEPS_DIR} AND NOT "$ENV{BFLOW_DEPS_DIR}" STREQUAL "")
  set(BFLOW_DEFAULT_IPOPT_PREFIX "$ENV{BFLOW_DEPS_DIR}/ipopt-3.14.19")
endif()

# _bflow_version_define(<file> <macro> <out>): the string a header #defines for <macro>.
function(_bflow_version_define file macro out)
  set(${out} "" PARENT_SCOPE)
  if(EXISTS "${file}")
    file(STRINGS "${file}" line REGEX "^#define[ \t]+${macro}[ \t]+\"[^\"]*\"" LIMIT_COUNT 1)
    if(line MATCHES "\"([^\"]*)\"")
      set(${out} "${CMAKE_MATCH_1}" PARENT_SCOPE)
    endif()
  endif()
endfunction()

# bflow_find_ipopt(<choice> <quiet>): see above. With <quiet> TRUE a missing IPOPT leaves
# bflow::ipopt undefined instead of stopping with an error.
function(bflow_find_ipopt choice quiet)
  set(prefix "")
  if(choice STREQUAL "auto")
    if(EXISTS "${BFLOW_DEFAULT_IPOPT_PREFIX}/lib/libipopt.so.3")
      set(prefix "${BFLOW_DEFAULT_IPOPT_PREFIX}")
    else()
      set(choice system)
    endif()
  elseif(choice STREQUAL "wheel")
    set(prefix "${BFLOW_DEFAULT_IPOPT_PREFIX}")
    if(NOT EXISTS "${prefix}/lib/libipopt.so.3")
      if(quiet)
        return()
      endif()
      message(FATAL_ERROR "BFLOW_IPOPT=wheel: no IPOPT in ${prefix}; run scripts/install-deps "
                          "(it installs IPOPT 3.14 from the casadi 3.8.2 wheel), or configure "
                          "with -DBFLOW_IPOPT=system for Debian's IPOPT 3.11")
    endif()
  elseif(NOT choice STREQUAL "system")
    set(prefix "${choice}")
  endif()

  if(choice STREQUAL "system")
    find_package(PkgConfig QUIET)
    if(PkgConfig_FOUND)
      pkg_check_modules(BFLOW_PC_IPOPT QUIET ipopt)
    endif()
    if(NOT BFLOW_PC_IPOPT_FOUND)
      if(quiet)
        return()
      endif()
      message(FATAL_ERROR "BFLOW_IPOPT=${BFLOW_IPOPT}: no IPOPT through pkg-config; run "
                          "scripts/install-deps (IPOPT 3.14 from PyPI's casadi wheel, or Debian's "
                          "coinor-libipopt-dev)")
    endif()
    if(NOT TARGET bflow::ipopt)
      add_library(bflow::ipopt INTERFACE IMPORTED GLOBAL)
      set_target_properties(bflow::ipopt PROPERTIES
                            INTERFACE_LINK_LIBRARIES "${BFLOW_PC_IPOPT_LINK_LIBRARIES}")
    endif()
    set(includes ${BFLOW_PC_IPOPT_INCLUDE_DIRS})
    find_path(BFLOW_SYSTEM_MUMPS_INCLUDE_DIR dmumps_c.h PATH_SUFFIXES mumps-seq mumps)
    # (A folder the compiler searches anyway, such as /usr/include, is left out: given again it
    # would reorder the compiler's own search.)
    if(BFLOW_SYSTEM_MUMPS_INCLUDE_DIR AND NOT BFLOW_SYSTEM_MUMPS_INCLUDE_DIR IN_LIST
                                              CMAKE_CXX_IMPLICIT_INCLUDE_DIRECTORIES)
      list(APPEND includes "${BFLOW_SYSTEM_MUMPS_INCLUDE_DIR}")
    endif()
    set(version_dirs ${includes} "${BFLOW_SYSTEM_MUMPS_INCLUDE_DIR}")
    list(GET BFLOW_PC_IPOPT_LINK_LIBRARIES 0 library)
    set(resolved system)
  else()
    get_filename_component(prefix "${prefix}" ABSOLUTE)
    set(library "")
    foreach(candidate IN ITEMS "${prefix}/lib/libipopt.so.3" "${prefix}/libipopt.so.3")
      if(NOT library AND EXISTS "${candidate}")
        set(library "${candidate}")
      endif()
    endforeach()
    if(NOT library OR NOT EXISTS "${prefix}/include/coin-or/IpoptConfig.h")
      if(quiet)
        return()
      endif()
      message(FATAL_ERROR "BFLOW_IPOPT=${BFLOW_IPOPT}: ${prefix} holds no IPOPT 3.14 (looked for "
                          "lib/libipopt.so.3 or libipopt.so.3, and include/coin-or/IpoptConfig.h)")
    endif()
    if(NOT TARGET bflow::ipopt)
      add_library(bflow::ipopt SHARED IMPORTED GLOBAL)
      set_target_properties(bflow::ipopt PROPERTIES IMPORTED_LOCATION "${library}"
                                                    IMPORTED_SONAME libipopt.so.3)
    endif()
    set(includes "${prefix}/include/coin-or" "${prefix}/include/coin-or/mumps")
    set(version_dirs ${includes})
    set(resolved "${prefix}")
  endif()

  set(ipopt_version "")
  set(mumps_version "")
  foreach(dir IN LISTS version_dirs)
    if(NOT ipopt_version)
      _bflow_version_define("${dir}/IpoptConfig.h" IPOPT_VERSION ipopt_version)
    endif()
    if(NOT mumps_version)
      _bflow_version_define("${dir}/dmumps_c.h" MUMPS_VERSION mumps_version)
    endif()
  endforeach()
  if(NOT ipopt_version AND BFLOW_PC_IPOPT_VERSION)
    set(ipopt_version "${BFLOW_PC_IPOPT_VERSION}")
  endif()
  set(spral FALSE)
  if(EXISTS "${library}")
    file(STRINGS "${library}" spral_symbol REGEX "spral_ssids_" LIMIT_COUNT 1)
    if(spral_symbol)
      set(spral TRUE)
    endif()
  endif()
  set(interposer FALSE)
  if(mumps_version AND mumps_version VERSION_LESS 5.8)
    set(interposer TRUE)
  endif()

  set(BFLOW_IPOPT_RESOLVED "${resolved}" PARENT_SCOPE)
  set(BFLOW_IPOPT_VERSION "${ipopt_version}" PARENT_SCOPE)
  set(BFLOW_MUMPS_VERSION "${mumps_version}" PARENT_SCOPE)
  set(options "")
  foreach(dir IN LISTS includes)
    list(APPEND options "-isystem${dir}")
  endforeach()
  if(resolved STREQUAL "system")
    list(APPEND options ${BFLOW_PC_IPOPT_CFLAGS_OTHER})
  endif()
  set(BFLOW_IPOPT_INCLUDE_DIRS "${includes}" PARENT_SCOPE)
  set(BFLOW_IPOPT_COMPILE_OPTIONS "${options}" PARENT_SCOPE)
  set(BFLOW_IPOPT_HAS_SPRAL ${spral} PARENT_SCOPE)
  set(BFLOW_MUMPS_INTERPOSER ${interposer} PARENT_SCOPE)
endfunction()
