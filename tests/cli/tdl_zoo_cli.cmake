# tdl forward / grad / train on bad input (clear message, non-zero exit) and, with the reference data
# (TOPOS_REFERENCE_DIR set), on a golden case: every output case.json names is written, and grad
# writes one file per parameter; tdl train on the karate club and tdl classify on batched
# point-cloud complexes beat chance by far.
# Arguments: -DTDL=<exe> -DWORK=<dir>.
file(REMOVE_RECURSE ${WORK})
file(MAKE_DIRECTORY ${WORK})

set(PROGRAM ${TDL})
include(${CMAKE_CURRENT_LIST_DIR}/run_program.cmake)

# Runs `tdl <task> --out WORK/<task> ARGN`, requires it to succeed and to write its accuracy
# curve, plot and summary; the summary's JSON goes to `summary_var`.
function(run_training_task task summary_var)
  execute_process(COMMAND ${TDL} ${task} --out ${WORK}/${task} ${ARGN} RESULT_VARIABLE rc OUTPUT_VARIABLE out ERROR_VARIABLE err)
  if(NOT rc EQUAL 0)
    message(FATAL_ERROR "tdl ${task} failed:\n${out}${err}")
  endif()
  foreach(f accuracy.csv accuracy.svg summary.json)
    if(NOT EXISTS ${WORK}/${task}/${f})
      message(FATAL_ERROR "tdl ${task} did not write ${f}")
    endif()
  endforeach()
  file(READ ${WORK}/${task}/summary.json summary)
  set(${summary_var} "${summary}" PARENT_SCOPE)
endfunction()

expect_failure("no case folder" "not a folder" forward --case ${WORK}/nowhere --out ${WORK}/o)
expect_failure("--case is required" "--case is required" forward --out ${WORK}/o)

# A case of an unknown model, and one whose config names an unknown parameter.
file(MAKE_DIRECTORY ${WORK}/bad/state_dict)
file(WRITE ${WORK}/bad/case.json "{\"model\": \"NoSuchNet\", \"config\": {}, \"forward\": [], \"outputs\": []}")
file(MAKE_DIRECTORY ${WORK}/bad/operators)
expect_failure("unknown model" "unknown model 'NoSuchNet'" forward --case ${WORK}/bad --out ${WORK}/o)
file(WRITE ${WORK}/bad/case.json "{\"model\": \"SCN2\", \"config\": {\"in_channels_0\": 2, \"in_channels_1\": 2, \"in_channels_2\": 2, \"width\": 3}, \"forward\": [], \"outputs\": []}")
expect_failure("unknown config parameter" "unknown config parameter 'width'" forward --case ${WORK}/bad --out ${WORK}/o)
file(WRITE ${WORK}/bad/case.json "{\"model\": \"SCN2\", \"config\": {\"in_channels_0\": 2, \"in_channels_1\": 2, \"in_channels_2\": 2}, \"forward\": [], \"outputs\": []}")
expect_failure("missing weights" "missing tensor 'layers.0.conv_0_to_0.weight'" forward --case ${WORK}/bad --out ${WORK}/o)
expect_failure("grad without grads/" "no grads/ folder" grad --case ${WORK}/bad --out ${WORK}/o)

# tdl train: the karate club (shipped data) with every model; each must beat chance (0.5) by far
# on the held-out members. A damaged data file is an error naming the line.
run_training_task(train summary --epochs 100)
foreach(model scn2 sccnn unigcnii)
  string(JSON acc GET "${summary}" models ${model} test_accuracy)
  string(JSON train_acc GET "${summary}" models ${model} train_accuracy)
  if(train_acc LESS 0.99)
    message(FATAL_ERROR "tdl train: ${model} does not fit its training members (${train_acc})\n${summary}")
  endif()
  if(acc LESS 0.75)
    message(FATAL_ERROR "tdl train: ${model} reaches only ${acc} test accuracy (chance is 0.5)\n${summary}")
  endif()
  message(STATUS "tdl train ${model}: test accuracy ${acc}")
endforeach()
file(WRITE ${WORK}/bad_graph.txt "node 0 0\nnode 1 1\nedge 0 7\n")
expect_failure("train on a bad graph" "edge (0, 7) names an unlisted node" train --data ${WORK}/bad_graph.txt --out ${WORK}/o)
file(WRITE ${WORK}/bad_graph.txt "node 0 0\nvertex 1 1\n")
expect_failure("train on a bad line" "bad_graph.txt:2: unknown line kind 'vertex'" train --data ${WORK}/bad_graph.txt --out ${WORK}/o)
expect_failure("train an unknown model" "unknown model 'gcn'" train --models gcn --out ${WORK}/o)

# tdl classify: point clouds told apart by their holes (three classes, chance 1/3), many clique
# complexes per optimizer step through ComplexBatch and a schedule.
run_training_task(classify summary)
string(JSON acc GET "${summary}" test_accuracy)
if(acc LESS 0.6)
  message(FATAL_ERROR "tdl classify reaches only ${acc} test accuracy (chance is 1/3)\n${summary}")
endif()
message(STATUS "tdl classify: test accuracy ${acc}")
expect_failure("classify with too few clouds" "--samples" classify --samples 3 --out ${WORK}/o)
expect_failure("classify without triangles" "has no triangles at --radius" classify --radius 0.001 --samples 6 --out ${WORK}/o)

set(REFERENCE "$ENV{TOPOS_REFERENCE_DIR}")
if(REFERENCE STREQUAL "")
  message(STATUS "SKIPPED: the golden-case run needs TOPOS_REFERENCE_DIR")
  return()
endif()
set(case ${REFERENCE}/tdl-golden/cases/scn2-rgg20)
execute_process(COMMAND ${TDL} forward --case ${case} --out ${WORK}/fwd RESULT_VARIABLE rc OUTPUT_VARIABLE out ERROR_VARIABLE err)
if(NOT rc EQUAL 0)
  message(FATAL_ERROR "forward on scn2-rgg20 failed:\n${out}${err}")
endif()
foreach(o out_0 out_1 out_2)
  if(NOT EXISTS ${WORK}/fwd/${o}.npy)
    message(FATAL_ERROR "forward did not write ${o}.npy")
  endif()
endforeach()
execute_process(COMMAND ${TDL} grad --case ${case} --out ${WORK}/grad RESULT_VARIABLE rc OUTPUT_VARIABLE out ERROR_VARIABLE err)
file(GLOB grads ${WORK}/grad/*.npy)
list(LENGTH grads n)
if(NOT rc EQUAL 0 OR NOT n EQUAL 6)
  message(FATAL_ERROR "grad on scn2-rgg20: exit ${rc}, ${n} files (expected 6)\n${out}${err}")
endif()
message(STATUS "ok: forward and grad on scn2-rgg20")
