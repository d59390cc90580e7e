# Helpers of the hopnet command-line tests (included by hopnet_cli.cmake and hopnet_pipeline.cmake):
# run the program and require success, or require a failure whose output names the problem; a
# failed run must not leave ${WORK}/out.json behind. Needs HOPNET and WORK.

function(expect_success name)
  execute_process(COMMAND ${HOPNET} ${ARGN} RESULT_VARIABLE rc OUTPUT_VARIABLE out ERROR_VARIABLE err)
  if(NOT rc EQUAL 0)
    message(FATAL_ERROR "${name}: failed (${rc})\n${out}${err}")
  endif()
  set(LAST_OUTPUT "${out}" PARENT_SCOPE)
  message(STATUS "ok: ${name}")
endfunction()

function(expect_failure name message)
  execute_process(COMMAND ${HOPNET} ${ARGN} RESULT_VARIABLE rc OUTPUT_VARIABLE out ERROR_VARIABLE err)
  if(rc EQUAL 0)
    message(FATAL_ERROR "${name}: expected a failure, got exit 0\n${out}${err}")
  endif()
  string(FIND "${out}${err}" "${message}" pos)
  if(pos EQUAL -1)
    message(FATAL_ERROR "${name}: expected the message '${message}', got:\n${out}${err}")
  endif()
  if(EXISTS ${WORK}/out.json)
    message(FATAL_ERROR "${name}: a failed run left ${WORK}/out.json behind")
  endif()
  message(STATUS "ok: ${name}")
endfunction()
