# Helpers of the tdl command-line tests (included by tdl_zoo_cli.cmake, tdl_lift_cli.cmake and
# tdl_topobench_cli.cmake): run the program and require a failure whose output names the
# problem. Needs TDL.

function(expect_failure name message)
  execute_process(COMMAND ${TDL} ${ARGN} RESULT_VARIABLE rc OUTPUT_VARIABLE out ERROR_VARIABLE err)
  if(rc EQUAL 0)
    message(FATAL_ERROR "${name}: expected a failure, got exit 0\n${out}${err}")
  endif()
  string(FIND "${out}${err}" "${message}" pos)
  if(pos EQUAL -1)
    message(FATAL_ERROR "${name}: expected the message '${message}', got:\n${out}${err}")
  endif()
  message(STATUS "ok: ${name}")
endfunction()
