# The paper's baselines in the hopnet program: info's parameter counts (FIGNet's from the
# reimplementation's construction, MeshGraphNet's from its layout), a short train, resume, rollout
# and evaluate per preset on a generated MOVi-A-like dataset, and the errors: conflicting presets,
# a checkpoint of one model resumed or started as another, a HOPNet checkpoint without statistics.
# Arguments: -DHOPNET=<exe> -DWORK=<dir>.
file(REMOVE_RECURSE ${WORK})
file(MAKE_DIRECTORY ${WORK})
set(PROGRAM ${HOPNET})
include(${CMAKE_CURRENT_LIST_DIR}/run_program.cmake)

function(expect_output name text)
  string(FIND "${LAST_OUTPUT}" "${text}" pos)
  if(pos EQUAL -1)
    message(FATAL_ERROR "${name}: expected '${text}' in:\n${LAST_OUTPUT}")
  endif()
endfunction()

expect_success("info fignet" info --config fignet)
expect_output("info fignet" "parameters: 5559430")
expect_output("info fignet" "tensors: 452")
expect_success("info mgn" info --config mgn)
expect_output("info mgn" "parameters: 2613507")
expect_success("info mgn-large-radius" info --config mgn-large-radius)
expect_output("info mgn-large-radius" "\"world_edge_radius\":0.3")
expect_failure("fignet,nox4" "preset 'nox4' sets architecture, which model fignet" info --config fignet,nox4)
expect_failure("mgn,fignet" "preset 'fignet' sets model" info --config mgn,fignet)

expect_success("generate" generate --dataset movi-a --seeds 1-6 --frames 24 --out ${WORK}/data)
file(WRITE ${WORK}/split.json "{\"train\": [1, 2, 3, 4], \"val\": [5], \"test\": [6]}")
set(train train --data ${WORK}/data --split-file ${WORK}/split.json --batch-timesteps 4
    --checkpoint-every 2 --val-timesteps 8)
foreach(preset fignet mgn mgn-large-radius)
  set(out ${WORK}/${preset})
  expect_success("train ${preset}" ${train} --config ${preset} --out ${out} --max-steps 2)
  expect_success("resume ${preset}" ${train} --config ${preset} --out ${out} --max-steps 4 --resume)
  file(STRINGS ${out}/steps.csv rows)
  list(LENGTH rows n)
  if(NOT n EQUAL 5)
    message(FATAL_ERROR "${preset}: steps.csv has ${n} lines after 2 + 2 steps, expected 5")
  endif()
  expect_success("info ${preset} checkpoint" info --checkpoint ${out}/checkpoint.pt)
  expect_output("info ${preset} checkpoint" "variant: ${preset}")
  expect_success("rollout ${preset}" rollout --checkpoint ${out}/checkpoint.pt --scene ${WORK}/data/6
                 --steps 6 --out ${out}/rollout.json)
  file(READ ${out}/rollout.json r)
  string(JSON frames GET "${r}" frames)
  if(NOT frames EQUAL 10)
    message(FATAL_ERROR "${preset}: the rollout has ${frames} frames, expected 4 + 6")
  endif()
  # Two step threads: the same poses.
  expect_success("rollout ${preset} on two step threads" rollout --checkpoint ${out}/checkpoint.pt
                 --scene ${WORK}/data/6 --steps 6 --step-threads 2 --out ${out}/rollout2.json)
  file(READ ${out}/rollout2.json r2)
  string(JSON p1 GET "${r}" positions)
  string(JSON p2 GET "${r2}" positions)
  if(NOT p1 STREQUAL p2)
    message(FATAL_ERROR "${preset}: two step threads moved the poses:\n${p1}\n${p2}")
  endif()
endforeach()
expect_success("evaluate fignet" evaluate --checkpoint ${WORK}/fignet/checkpoint.pt --data ${WORK}/data
               --split-file ${WORK}/split.json --steps 8 --out ${WORK}/eval --no-report)
file(READ ${WORK}/eval/metrics.json m)
string(JSON model GET "${m}" model)
if(NOT model STREQUAL "fignet")
  message(FATAL_ERROR "evaluate named the model '${model}', expected fignet")
endif()

# Statistics per checkpoint: a baseline's are in its checkpoint, so its entry is '-'.
expect_success("evaluate two baselines, '-' for each one's statistics" evaluate --checkpoint ${WORK}/fignet/checkpoint.pt
               ${WORK}/mgn/checkpoint.pt --stats - - --data ${WORK}/data --split-file ${WORK}/split.json --steps 8
               --out ${WORK}/eval_dash --no-report)
expect_failure("evaluate with a statistics file for a baseline" "goes with ${WORK}/fignet/checkpoint.pt, a fignet checkpoint, which holds its own statistics; write '-' there"
               evaluate --checkpoint ${WORK}/fignet/checkpoint.pt ${WORK}/mgn/checkpoint.pt --stats ${WORK}/split.json -
               --data ${WORK}/data --split-file ${WORK}/split.json --steps 8 --out ${WORK}/eval_bad --no-report)

# Several checkpoints: one table with every model's rows, in order, beside constant velocity.
expect_success("evaluate three" evaluate --checkpoint ${WORK}/fignet/checkpoint.pt
               ${WORK}/mgn/checkpoint.pt ${WORK}/mgn-large-radius/checkpoint.pt --data ${WORK}/data
               --split-file ${WORK}/split.json --steps 8 --out ${WORK}/eval3 --no-report)
file(READ ${WORK}/eval3/metrics.json m)
foreach(i name IN ZIP_LISTS "0;1;2;3" "fignet;mgn;mgn-large-radius;constant_velocity")
  string(JSON got GET "${m}" model_order ${i})
  if(NOT got STREQUAL name)
    message(FATAL_ERROR "evaluate's model ${i} is '${got}', expected ${name}")
  endif()
endforeach()
file(READ ${WORK}/eval3/table.md table)
foreach(row "| fignet | pos_rmse" "| mgn | pos_rmse" "| mgn-large-radius | pos_rmse" "| constant_velocity | pos_rmse")
  string(FIND "${table}" "${row}" pos)
  if(pos EQUAL -1)
    message(FATAL_ERROR "table.md has no row '${row}':\n${table}")
  endif()
endforeach()

expect_failure("resume as another model" "mgn/checkpoint.pt: a mgn checkpoint"
               ${train} --config fignet --out ${WORK}/mgn --max-steps 6 --resume)
expect_failure("resume with another radius" "--config asks for"
               ${train} --config mgn --out ${WORK}/mgn-large-radius --max-steps 6 --resume)
expect_failure("init from another model" "the configuration asks for fignet"
               ${train} --config fignet --out ${WORK}/x --init ${WORK}/mgn/checkpoint.pt --max-steps 1)
expect_failure("HOPNet's options" "are HOPNet's"
               ${train} --config fignet --out ${WORK}/y --hidden 64 --max-steps 1)
expect_failure("HOPNet's contact cache" "--contact-cache-mb are HOPNet's"
               ${train} --config fignet --out ${WORK}/y2 --contact-cache-mb 0 --max-steps 1)
expect_success("hopnet init" init --out ${WORK}/hopnet.pt --hidden 16)
expect_failure("HOPNet without statistics" "--stats is required"
               rollout --checkpoint ${WORK}/hopnet.pt --scene ${WORK}/data/6 --out ${WORK}/h.json)
expect_failure("HOPNet as a baseline" "a hopnet checkpoint"
               ${train} --config mgn --out ${WORK}/z --init ${WORK}/hopnet.pt --max-steps 1)
