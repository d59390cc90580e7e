# Helpers of the command-line tests (hopnet_cli, hopnet_pipeline, tdl_zoo_cli, tdl_lift_cli,
# tdl_topobench_cli, example_custom_backbone): run PROGRAM and require success, or a failure
# whose output names the problem. With FAILED_RUN_LEAVES_NO set to a path, a failed run must not
# leave that file behind (nothing half-written). Needs PROGRAM.

function(expect_success name)
  execute_process(COMMAND ${PROGRAM} ${ARGN} RESULT_VARIABLE rc OUTPUT_VARIABLE out ERROR_VARIABLE err)
  if(NOT rc EQUAL 0)
    message(FATAL_ERROR "${name}: failed (${rc})\n${out}${err}")
  endif()
  set(LAST_OUTPUT "${out}" PARENT_SCOPE)
  message(STATUS "ok: ${name}")
endfunction()

function(expect_failure name message)
  execute_process(COMMAND ${PROGRAM} ${ARGN} RESULT_VARIABLE rc OUTPUT_VARIABLE out ERROR_VARIABLE err)
  if(rc EQUAL 0)
    message(FATAL_ERROR "${name}: expected a failure, got exit 0\n${out}${err}")
  endif()
  string(FIND "${out}${err}" "${message}" pos)
  if(pos EQUAL -1)
    message(FATAL_ERROR "${name}: expected the message '${message}', got:\n${out}${err}")
  endif()
  if(FAILED_RUN_LEAVES_NO AND EXISTS ${FAILED_RUN_LEAVES_NO})
    message(FATAL_ERROR "${name}: a failed run left ${FAILED_RUN_LEAVES_NO} behind")
  endif()
  message(STATUS "ok: ${name}")
endfunction()
