# The sheaf diffusion example (examples/sheaf_diffusion.cpp: two operations defined outside
# topos): bad input is a clear error; with TOPOS_DATASETS_DIR, a short training on Cora must beat
# the majority class on the test nodes.
execute_process(COMMAND ${EXE} --data-dir ${WORK}/missing --dataset Cora
  RESULT_VARIABLE rc OUTPUT_VARIABLE out ERROR_VARIABLE err)
if(NOT rc OR NOT err MATCHES "ind\\.cora")
  message(FATAL_ERROR "a missing dataset folder should fail naming the file (rc ${rc}): ${out}${err}")
endif()
foreach(bad "--epochs;x;expects a number in \\[1, 100000\\], got 'x'" "--bogus;unknown option '--bogus'"
            "--dataset;Cora;--data-dir is required")
  list(POP_BACK bad expected)
  execute_process(COMMAND ${EXE} ${bad} RESULT_VARIABLE rc OUTPUT_VARIABLE out ERROR_VARIABLE err)
  if(NOT rc OR NOT err MATCHES "${expected}")
    message(FATAL_ERROR "'${bad}' should fail with '${expected}' (rc ${rc}): ${out}${err}")
  endif()
endforeach()
if(NOT DEFINED ENV{TOPOS_DATASETS_DIR} OR "$ENV{TOPOS_DATASETS_DIR}" STREQUAL "")
  message("SKIPPED: TOPOS_DATASETS_DIR is not set; the example trains on Cora from it")
  return()
endif()
execute_process(COMMAND ${EXE} --data-dir $ENV{TOPOS_DATASETS_DIR} --dataset Cora --epochs 60
  --print --require-beats-majority RESULT_VARIABLE rc OUTPUT_VARIABLE out ERROR_VARIABLE err)
message("${out}${err}")
if(rc)
  message(FATAL_ERROR "sheaf_diffusion failed (${rc})")
endif()
if(NOT out MATCHES "Δ\\[layers\\.1; incidence_1")
  message(FATAL_ERROR "the printed schedule should show the user's sheaf Laplacian")
endif()
