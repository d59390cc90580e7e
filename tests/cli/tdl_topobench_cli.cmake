# tdl topobench on bad input (a clear message, a non-zero exit, nothing written over) and, with the
# raw datasets (TOPOS_DATASETS_DIR set), a short MUTAG table: CWN and UniGNN2 on one split with
# the whole protocol (about 10 s) each beat the majority class on the test split, and a second
# start resumes (runs nothing, keeps runs.csv).
# Arguments: -DTDL=<exe> -DWORK=<dir> -DMODE=bad|mutag (two ctest cases).
file(REMOVE_RECURSE ${WORK})
file(MAKE_DIRECTORY ${WORK})

set(PROGRAM ${TDL})
include(${CMAKE_CURRENT_LIST_DIR}/run_program.cmake)
macro(expect_failure_topobench name message)
  expect_failure("${name}" "${message}" topobench ${ARGN})
endmacro()

if(MODE STREQUAL "bad")
# A hyperparameter file of our own so that the bad-input cases need no dataset.
file(WRITE ${WORK}/data/README.md "test data\n")
file(WRITE ${WORK}/data/topobench/reproduce-hparams.txt
  "# test\nsimplicial/scn MUTAG lr=0.01 hid=8 L=1 readout=NoReadOut dropout=0.5 bs=32 dataset.split_params.data_seed=0 trainer.max_epochs=5 trainer.min_epochs=1 trainer.check_val_every_n_epoch=1 callbacks.early_stopping.patience=2\n")
expect_failure_topobench("unknown model" "unknown TopoBench model 'SCNX'"
  --data-dir ${WORK}/data --models SCNX --datasets MUTAG --out ${WORK}/o)
expect_failure_topobench("unknown dataset" "unknown TopoBench dataset 'MUTANT'"
  --data-dir ${WORK}/data --models SCN --datasets MUTANT --out ${WORK}/o)
expect_failure_topobench("no hyperparameters for the pair" "no hyperparameters for CWN"
  --data-dir ${WORK}/data --models CWN --datasets MUTAG --out ${WORK}/o)
expect_failure_topobench("missing hparams file" "nowhere"
  --data-dir ${WORK}/nowhere --models SCN --datasets MUTAG --out ${WORK}/o)
expect_failure_topobench("negative --factor-above" "--factor-above"
  --data-dir ${WORK}/data --models SCN --datasets MUTAG --factor-above -1 --out ${WORK}/o)
expect_failure_topobench("no intra-op thread" "--threads: Value 0 not in range 1 to 64"
  --data-dir ${WORK}/data --models SCN --datasets MUTAG --threads 0 --out ${WORK}/o)
expect_failure_topobench("bad split" "--splits"
  --data-dir ${WORK}/data --models SCN --datasets MUTAG --splits 1,x --out ${WORK}/o)
file(WRITE ${WORK}/data/topobench/bad-hparams.txt "simplicial/scn MUTAG lr=abc hid=8\n")
expect_failure_topobench("malformed hparams" "bad-hparams.txt:1: lr=abc is not a number"
  --data-dir ${WORK}/data --hparams ${WORK}/data/topobench/bad-hparams.txt --models SCN --datasets MUTAG --out ${WORK}/o)
# A curves.csv of another format is named, and left as it was.
file(MAKE_DIRECTORY ${WORK}/bad_curves)
file(WRITE ${WORK}/bad_curves/curves.csv "epoch,loss,val_accuracy\n1,0.5,0.5\n")
expect_failure_topobench("curves.csv of another format" "curves.csv: expected the header model,dataset,split_seed"
  --data-dir ${WORK}/data --models SCN --datasets MUTAG --out ${WORK}/bad_curves)
file(READ ${WORK}/bad_curves/curves.csv after)
if(NOT after STREQUAL "epoch,loss,val_accuracy\n1,0.5,0.5\n")
  message(FATAL_ERROR "a failed start changed curves.csv")
endif()
file(WRITE ${WORK}/bad_curves/curves.csv "model,dataset,split_seed,epoch,loss,val_accuracy\nSCN,MUTAG,0,x,0.5,0.5\n")
expect_failure_topobench("curves.csv with a malformed row" "curves.csv:2: malformed row 'SCN,MUTAG,0,x,0.5,0.5'"
  --data-dir ${WORK}/data --models SCN --datasets MUTAG --out ${WORK}/bad_curves)
# A malformed runs.csv is named with its line and left as it was.
file(MAKE_DIRECTORY ${WORK}/bad_runs)
set(bad "model,dataset,split_seed,test_accuracy,best_epoch,epochs,seconds\nSCN,MUTAG,0,1.5,1,1,1\n")
file(WRITE ${WORK}/bad_runs/runs.csv "${bad}")
expect_failure_topobench("malformed runs.csv" "runs.csv:2: test_accuracy outside [0, 1]"
  --data-dir ${WORK}/data --models SCN --datasets MUTAG --out ${WORK}/bad_runs)
file(READ ${WORK}/bad_runs/runs.csv after)
if(NOT after STREQUAL bad)
  message(FATAL_ERROR "a failed start changed runs.csv")
endif()
# A folder of float32 runs (no OUT/matmul_precision) takes no bfloat16 runs, and an unknown
# precision is refused by name.
file(MAKE_DIRECTORY ${WORK}/f32_runs)
file(WRITE ${WORK}/f32_runs/runs.csv
  "model,dataset,split_seed,test_accuracy,best_epoch,epochs,seconds\nSCN,MUTAG,0,0.5,1,1,1\n")
expect_failure_topobench("bfloat16 runs into a float32 folder"
  "holds runs at --matmul-precision highest, not medium: give another --out, or --matmul-precision highest"
  --data-dir ${WORK}/data --models SCN --datasets MUTAG --matmul-precision medium --out ${WORK}/f32_runs)
if(EXISTS ${WORK}/f32_runs/matmul_precision)
  message(FATAL_ERROR "a refused start marked the folder")
endif()
expect_failure_topobench("unknown matmul precision" "--matmul-precision: low not in {highest,medium}"
  --data-dir ${WORK}/data --models SCN --datasets MUTAG --matmul-precision low --out ${WORK}/o)
# Without AVX-512 BF16 (TOPOS_DISABLE_BF16=1 stands for such a CPU) the backbones' products would
# stay float32, so a bfloat16 table is refused rather than labelled so.
execute_process(COMMAND ${CMAKE_COMMAND} -E env TOPOS_DISABLE_BF16=1 ${TDL} topobench
  --data-dir ${WORK}/data --models SCN --datasets MUTAG --matmul-precision medium --out ${WORK}/no_bf16
  RESULT_VARIABLE rc OUTPUT_VARIABLE out ERROR_VARIABLE err)
string(FIND "${err}" "this CPU has no AVX-512 BF16, so the backbones' own products (their weights and sparse weights) would stay float32; use --matmul-precision highest" said)
if(rc EQUAL 0 OR said EQUAL -1 OR EXISTS ${WORK}/no_bf16/matmul_precision)
  message(FATAL_ERROR "--matmul-precision medium without AVX-512 BF16 was not refused:\n${out}${err}")
endif()
message(STATUS "ok: --matmul-precision medium refused without AVX-512 BF16")
return()
endif()

if(NOT DEFINED ENV{TOPOS_DATASETS_DIR} OR "$ENV{TOPOS_DATASETS_DIR}" STREQUAL "")
  message(STATUS "SKIPPED: the MUTAG table needs the raw datasets; set TOPOS_DATASETS_DIR to ../shared/datasets")
  return()
endif()
set(data $ENV{TOPOS_DATASETS_DIR})
execute_process(COMMAND ${TDL} topobench --data-dir ${data} --models CWN,UniGNN2 --datasets MUTAG --splits 0
  --out ${WORK}/mutag RESULT_VARIABLE rc OUTPUT_VARIABLE out ERROR_VARIABLE err)
if(NOT rc EQUAL 0)
  message(FATAL_ERROR "tdl topobench failed:\n${out}${err}")
endif()
foreach(f runs.csv summary.csv baselines.csv index.html curves.csv)
  if(NOT EXISTS ${WORK}/mutag/${f})
    message(FATAL_ERROR "tdl topobench did not write ${f}")
  endif()
endforeach()
# Every run's validation curve in one file, a row per check.
foreach(m CWN UniGNN2)
  file(STRINGS ${WORK}/mutag/curves.csv checks REGEX "^${m},MUTAG,0,[0-9]+,")
  if(NOT checks)
    message(FATAL_ERROR "curves.csv has no validation checks of ${m} on MUTAG split 0")
  endif()
endforeach()
file(STRINGS ${WORK}/mutag/baselines.csv base REGEX "^MUTAG,0,")
string(REPLACE "," ";" base "${base}")
list(GET base 2 majority)
file(STRINGS ${WORK}/mutag/runs.csv rows REGEX "^(CWN|UniGNN2),MUTAG,0,")
list(LENGTH rows n)
if(NOT n EQUAL 2)
  message(FATAL_ERROR "expected 2 runs in runs.csv, got ${n}")
endif()
foreach(row ${rows})
  string(REPLACE "," ";" f "${row}")
  list(GET f 0 model)
  list(GET f 3 acc)
  if(NOT acc GREATER majority)
    message(FATAL_ERROR "${model} on MUTAG split 0: test accuracy ${acc} does not beat the majority class ${majority}")
  endif()
  message(STATUS "ok: ${model} on MUTAG split 0: ${acc} > majority ${majority}")
endforeach()
# Started again on the same folder: nothing left to run, runs.csv unchanged.
file(READ ${WORK}/mutag/runs.csv before)
execute_process(COMMAND ${TDL} topobench --data-dir ${data} --models CWN,UniGNN2 --datasets MUTAG --splits 0
  --out ${WORK}/mutag RESULT_VARIABLE rc OUTPUT_VARIABLE out ERROR_VARIABLE err)
string(FIND "${err}" "0 runs to do, 2 already" pos)
if(NOT rc EQUAL 0 OR pos EQUAL -1)
  message(FATAL_ERROR "the second start did not resume:\n${out}${err}")
endif()
file(READ ${WORK}/mutag/runs.csv after)
if(NOT after STREQUAL before)
  message(FATAL_ERROR "resuming changed runs.csv")
endif()
message(STATUS "ok: resumed")

# --factor-above 0 keeps the rank-1 Laplacians of every dataset as products of incidences (as on
# REDDIT-BINARY): CCCN and SCN say so and run.
execute_process(COMMAND ${TDL} topobench --data-dir ${data} --models CCCN,SCN --datasets MUTAG --splits 0
  --max-epochs 5 --factor-above 0 --out ${WORK}/factored RESULT_VARIABLE rc OUTPUT_VARIABLE out ERROR_VARIABLE err)
string(FIND "${err}" "SCN on MUTAG: its rank-1 down Laplacian" said)
string(FIND "${err}" "they are applied as products of incidences" how)
file(STRINGS ${WORK}/factored/runs.csv rows REGEX "^(CCCN|SCN),MUTAG,0,")
list(LENGTH rows n)
if(NOT rc EQUAL 0 OR said EQUAL -1 OR how EQUAL -1 OR NOT n EQUAL 2)
  message(FATAL_ERROR "--factor-above 0: expected CCCN and SCN run with factored Laplacians:\n${out}${err}")
endif()
message(STATUS "ok: factored rank-1 Laplacians")

# GCCN has no line of its own: it runs with MUTAG's CWN line (its own width, layers, readout).
execute_process(COMMAND ${TDL} topobench --data-dir ${data} --models GCCN --datasets MUTAG --splits 0
  --max-epochs 5 --out ${WORK}/gccn RESULT_VARIABLE rc OUTPUT_VARIABLE out ERROR_VARIABLE err)
file(STRINGS ${WORK}/gccn/runs.csv rows REGEX "^GCCN,MUTAG,0,")
if(NOT rc EQUAL 0 OR NOT rows)
  message(FATAL_ERROR "GCCN on MUTAG (CWN's line) did not run:\n${out}${err}")
endif()
message(STATUS "ok: GCCN with CWN's line")

# --matmul-precision medium: bfloat16 products; the folder says so, and a float32 start on it is
# refused. Only where the CPU has AVX-512 BF16 (elsewhere medium is refused, tested above).
file(READ /proc/cpuinfo cpuinfo LIMIT 100000)
string(FIND "${cpuinfo}" " avx512_bf16" has_bf16)
if(has_bf16 EQUAL -1 OR "$ENV{TOPOS_DISABLE_BF16}" MATCHES "^[^0]")
  message(STATUS "skipped: --matmul-precision medium (this CPU has no AVX-512 BF16)")
else()
execute_process(COMMAND ${TDL} topobench --data-dir ${data} --models CWN --datasets MUTAG --splits 0
  --max-epochs 5 --matmul-precision medium --out ${WORK}/medium
  RESULT_VARIABLE rc OUTPUT_VARIABLE out ERROR_VARIABLE err)
file(STRINGS ${WORK}/medium/runs.csv rows REGEX "^CWN,MUTAG,0,")
if(NOT rc EQUAL 0 OR NOT rows OR NOT EXISTS ${WORK}/medium/matmul_precision)
  message(FATAL_ERROR "CWN on MUTAG at --matmul-precision medium did not run:\n${out}${err}")
endif()
file(READ ${WORK}/medium/matmul_precision marker)
execute_process(COMMAND ${TDL} topobench --data-dir ${data} --models CWN --datasets MUTAG --splits 3
  --max-epochs 5 --out ${WORK}/medium RESULT_VARIABLE rc OUTPUT_VARIABLE out ERROR_VARIABLE err)
string(FIND "${err}" "holds runs at --matmul-precision medium, not highest" said)
if(NOT marker STREQUAL "medium" OR rc EQUAL 0 OR said EQUAL -1)
  message(FATAL_ERROR "a float32 start on a bfloat16 folder was not refused:\n${out}${err}")
endif()
message(STATUS "ok: --matmul-precision medium")
endif()

# A run that fails (here: CWN 3,000,000 wide cannot allocate its weights) marks its cell failed in
# not_run.csv with the error, the other cells still run, and the exit status is 1.
file(WRITE ${WORK}/fail/hparams.txt
  "graph/gcn MUTAG lr=0.01 hid=8 L=1 dropout=0.5 bs=32 dataset.split_params.data_seed=0 trainer.max_epochs=5 trainer.min_epochs=1 trainer.check_val_every_n_epoch=1 callbacks.early_stopping.patience=2\n"
  "cell/cwn MUTAG lr=0.01 hid=3000000 L=1 readout=PropagateSignalDown dropout=0.5 bs=32 dataset.split_params.data_seed=0,3 trainer.max_epochs=5 trainer.min_epochs=1 trainer.check_val_every_n_epoch=1 callbacks.early_stopping.patience=2\n")
execute_process(COMMAND ${TDL} topobench --data-dir ${data} --hparams ${WORK}/fail/hparams.txt
  --models CWN,GCN --datasets MUTAG --out ${WORK}/fail/out RESULT_VARIABLE rc OUTPUT_VARIABLE out ERROR_VARIABLE err)
file(READ ${WORK}/fail/out/not_run.csv not_run)
file(STRINGS ${WORK}/fail/out/runs.csv gcn REGEX "^GCN,MUTAG,0,")
string(FIND "${not_run}" "CWN,MUTAG,\"split 0 failed: " pos)
if(NOT rc EQUAL 1 OR pos EQUAL -1 OR NOT gcn)
  message(FATAL_ERROR "a failing cell: expected exit 1, CWN failed in not_run.csv and GCN's run (exit ${rc}):\n${not_run}\n${out}${err}")
endif()
message(STATUS "ok: a failing cell is recorded and the others run")

# scripts/topobench_clean_time.py --only CWN: CWN's MUTAG cell is timed again (one epoch), and
# UniGNN2's keeps the seconds per epoch of the clean-time file already there.
if(NOT PYTHON3)
  message(STATUS "SKIPPED: topobench_clean_time.py needs python3")
  return()
endif()
set(header "model,dataset,seconds_per_epoch,runs,epochs,estimated_seconds\n")
file(WRITE ${WORK}/clean.csv "${header}CWN,MUTAG,999.0000,1,1,999.0\nUniGNN2,MUTAG,123.0000,1,1,123.0\n")
execute_process(COMMAND ${PYTHON3} ${SCRIPTS}/topobench_clean_time.py --only CWN ${TDL} ${data}
  ${WORK}/mutag/runs.csv ${WORK}/clean.csv 1 RESULT_VARIABLE rc OUTPUT_VARIABLE out ERROR_VARIABLE err)
file(STRINGS ${WORK}/clean.csv uni REGEX "^UniGNN2,MUTAG,123.0000,1,")
file(STRINGS ${WORK}/clean.csv cwn REGEX "^CWN,MUTAG,")
string(REPLACE "," ";" cwn_fields "${cwn}")
list(GET cwn_fields 2 cwn_seconds)
if(NOT rc EQUAL 0 OR NOT uni OR cwn_seconds STREQUAL "999.0000" OR NOT cwn_seconds GREATER 0)
  message(FATAL_ERROR "clean time --only CWN: expected CWN timed again and UniGNN2 kept (exit ${rc}):\n${uni}\n${cwn}\n${out}${err}")
endif()
execute_process(COMMAND ${PYTHON3} ${SCRIPTS}/topobench_clean_time.py --only CWN ${TDL} ${data}
  ${WORK}/mutag/runs.csv ${WORK}/nowhere.csv 1 RESULT_VARIABLE rc OUTPUT_VARIABLE out ERROR_VARIABLE err)
string(FIND "${err}" "which does not exist" pos)
if(rc EQUAL 0 OR pos EQUAL -1)
  message(FATAL_ERROR "clean time --only without a clean-time file: expected an error naming it:\n${out}${err}")
endif()
message(STATUS "ok: clean time of one model again, the others kept (CWN ${cwn_seconds} s per epoch)")

# --fixed: CWN's MUTAG cell timed at 1 and 3 epochs, its run's fixed seconds apart from its
# epochs; the estimate is fixed + epochs x seconds per epoch, and UniGNN2's row is kept (no fixed
# cost in the old file). A second count not above EPOCHS, or not a number, is refused with a
# message naming the option.
execute_process(COMMAND ${PYTHON3} ${SCRIPTS}/topobench_clean_time.py --only CWN --fixed 3 ${TDL}
  ${data} ${WORK}/mutag/runs.csv ${WORK}/clean.csv 1 RESULT_VARIABLE rc OUTPUT_VARIABLE out
  ERROR_VARIABLE err)
file(STRINGS ${WORK}/clean.csv cwn REGEX "^CWN,MUTAG,")
string(REPLACE "," ";" cwn_fields "${cwn}")
list(LENGTH cwn_fields n)
if(NOT rc EQUAL 0 OR NOT n EQUAL 7)
  message(FATAL_ERROR "clean time --fixed: expected a row of 7 fields (exit ${rc}):\n${cwn}\n${out}${err}")
endif()
list(GET cwn_fields 2 per_epoch)
list(GET cwn_fields 3 n_runs)
list(GET cwn_fields 4 n_epochs)
list(GET cwn_fields 5 estimate)
list(GET cwn_fields 6 fixed)
# Within the rounding of the printed figures (CMake's math is integer).
execute_process(COMMAND ${PYTHON3} -c
  "p,r,e,f,s=${per_epoch},${n_runs},${n_epochs},${fixed},${estimate}; print(int(abs(p*e+f*r-s)<0.06+0.005*r+0.0001*e))"
  OUTPUT_VARIABLE sums OUTPUT_STRIP_TRAILING_WHITESPACE)
file(STRINGS ${WORK}/clean.csv uni REGEX "^UniGNN2,MUTAG,123.0000,1,.*,0.00$")
if(NOT sums STREQUAL "1" OR NOT uni)
  message(FATAL_ERROR "clean time --fixed: the estimate ${estimate} is not fixed ${fixed} x ${n_runs} runs + ${per_epoch} x ${n_epochs} epochs:\n${cwn}")
endif()
foreach(bad "--fixed;1" "--fixed;x")
  execute_process(COMMAND ${PYTHON3} ${SCRIPTS}/topobench_clean_time.py --only CWN ${bad} ${TDL}
    ${data} ${WORK}/mutag/runs.csv ${WORK}/clean.csv 1 RESULT_VARIABLE rc OUTPUT_VARIABLE out
    ERROR_VARIABLE err)
  string(FIND "${err}" "--fixed" pos)
  if(rc EQUAL 0 OR pos EQUAL -1)
    message(FATAL_ERROR "clean time ${bad}: expected an error naming --fixed:\n${out}${err}")
  endif()
endforeach()
message(STATUS "ok: clean time with fixed costs apart (CWN ${per_epoch} s per epoch, ${fixed} s per run)")
