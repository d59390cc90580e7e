# Installs topos into a temporary prefix, configures and builds a consumer project with
# find_package(topos REQUIRED COMPONENTS nn geometry zoo), against the compiled topos::nn and
# header-only, and one on topos::zoo, and runs them; with PYTHON, imports the installed Python
# package first. MALLOC: tcmalloc or glibc, the malloc topos::tcmalloc brings.
file(REMOVE_RECURSE "${WORK_DIR}")
set(prefix "${WORK_DIR}/prefix")
execute_process(COMMAND ${CMAKE_COMMAND} --install "${TOPOS_BINARY_DIR}" --prefix "${prefix}" RESULT_VARIABLE rc)
if(rc)
  message(FATAL_ERROR "cmake --install failed: ${rc}")
endif()
# The Python package (TOPOS_PYTHON builds: PYTHON is set), imported from the prefix alone.
if(PYTHON)
  execute_process(COMMAND ${CMAKE_COMMAND} -E env PYTHONPATH=${prefix}/${PYTHON_INSTALL_DIR}
      PYTHONDONTWRITEBYTECODE=1 ${PYTHON} -c
      "import topos; assert topos.__file__.startswith('${prefix}/'), topos.__file__; print(topos.SimplicialComplex([[0, 1, 2]]).shape)"
    WORKING_DIRECTORY "${WORK_DIR}" RESULT_VARIABLE rc OUTPUT_VARIABLE out ERROR_VARIABLE err)
  if(rc OR NOT out MATCHES "\\(3, 3, 1\\)")
    message(FATAL_ERROR "the installed Python package failed (${rc}): ${out}${err}")
  endif()
  message(STATUS "the installed Python package said: ${out}")
endif()
set(launcher)
find_program(CCACHE ccache)
if(CCACHE)
  set(launcher -DCMAKE_CXX_COMPILER_LAUNCHER=${CCACHE})
endif()
execute_process(COMMAND ${CMAKE_COMMAND} -S "${CONSUMER_SOURCE_DIR}" -B "${WORK_DIR}/build"
  -DCMAKE_PREFIX_PATH=${prefix} -DCMAKE_BUILD_TYPE=${CMAKE_BUILD_TYPE} ${launcher} RESULT_VARIABLE rc)
if(rc)
  message(FATAL_ERROR "configuring the consumer failed: ${rc}")
endif()
execute_process(COMMAND ${CMAKE_COMMAND} --build "${WORK_DIR}/build" RESULT_VARIABLE rc)
if(rc)
  message(FATAL_ERROR "building the consumer failed: ${rc}")
endif()
foreach(exe consumer consumer_header_only consumer_zoo)
  execute_process(COMMAND "${WORK_DIR}/build/${exe}" RESULT_VARIABLE rc OUTPUT_VARIABLE out)
  message(STATUS "${exe} said: ${out}")
  if(rc OR NOT out MATCHES "consumer ok")
    message(FATAL_ERROR "${exe} failed: ${rc}")
  endif()
  # Only the consumer links topos::tcmalloc: it runs on MALLOC, the others on glibc's.
  set(want glibc)
  if(exe STREQUAL "consumer")
    set(want ${MALLOC})
  endif()
  if(NOT out MATCHES "malloc ${want}( |\n|$)")
    message(FATAL_ERROR "${exe} should run on ${want}'s malloc: ${out}")
  endif()
endforeach()
