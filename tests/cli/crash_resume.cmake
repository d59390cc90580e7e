# Crash-safe long work: `hopnet generate` and `hopnet train` killed with SIGKILL at many points
# (halfway through a file write, between the renames of a checkpoint commit, the parent alone
# while its generation jobs run, at a random moment mid-epoch), then resumed: the dataset and
# the final checkpoint must be byte-identical to an uninterrupted run with the same seed.
# Kill points come from TOPOS_CRASH_TEST_POINT (io/atomic_file.hpp: the n-th crash point of a
# process kills it) and from `timeout -s KILL`. Arguments: -DHOPNET=<exe> -DWORK=<dir>.
file(REMOVE_RECURSE ${WORK})
file(MAKE_DIRECTORY ${WORK})

# Runs hopnet with TOPOS_CRASH_TEST_POINT=point (0: none); sets RC.
function(run point)
  execute_process(COMMAND ${CMAKE_COMMAND} -E env TOPOS_CRASH_TEST_POINT=${point} ${HOPNET} ${ARGN}
    RESULT_VARIABLE rc OUTPUT_VARIABLE out ERROR_VARIABLE err)
  set(RC "${rc}" PARENT_SCOPE)
  set(OUT "${out}${err}" PARENT_SCOPE)
endfunction()

function(require_same what a b)
  file(SHA256 ${a} ha)
  file(SHA256 ${b} hb)
  if(NOT ha STREQUAL hb)
    message(FATAL_ERROR "${what}: ${b} differs from the uninterrupted run's ${a}")
  endif()
endfunction()

# No file of a finished run may be a leftover of an interrupted write.
function(require_no_leftovers dir)
  file(GLOB_RECURSE left ${dir}/*.tmp ${dir}/*.next ${dir}/*.journal)
  if(left)
    message(FATAL_ERROR "a finished run left partial files behind: ${left}")
  endif()
endfunction()

# ---- generate ------------------------------------------------------------------------------
set(gen generate --dataset movi-a --seeds 1-4 --frames 24 --jobs 2)
run(0 ${gen} --format topos --out ${WORK}/gen_ref)
if(NOT RC EQUAL 0)
  message(FATAL_ERROR "uninterrupted generate failed:\n${OUT}")
endif()
run(0 ${gen} --format kubric --out ${WORK}/gen_ref_kubric)

# Each job writes 2 scenes: points 1 and 2 kill a job halfway through a metadata.json; point 3
# kills the parent halfway through dataset.json, after both arrays (the packing).
foreach(format topos kubric)
  foreach(point 1 2 3)
    set(out ${WORK}/gen_${format}_${point})
    run(${point} ${gen} --format ${format} --out ${out})
    if(RC EQUAL 0 AND NOT (format STREQUAL "kubric" AND point EQUAL 3))
      message(FATAL_ERROR "generate with crash point ${point} was not killed:\n${OUT}")
    endif()
    if(format STREQUAL "topos" AND EXISTS ${out}/dataset.json)
      message(FATAL_ERROR "generate killed at point ${point} left a dataset.json behind")
    endif()
    run(0 ${gen} --format ${format} --out ${out})
    if(NOT RC EQUAL 0)
      message(FATAL_ERROR "resuming generate after crash point ${point} failed:\n${OUT}")
    endif()
    if(format STREQUAL "topos")
      foreach(f dataset.json positions.npy quaternions.npy)
        require_same("generate killed at point ${point}, resumed" ${WORK}/gen_ref/${f} ${out}/${f})
      endforeach()
      if(EXISTS ${out}/staging)
        message(FATAL_ERROR "resumed generate left its staging folder")
      endif()
    else()
      foreach(s 1 2 3 4)
        require_same("generate (kubric) killed at point ${point}, resumed" ${WORK}/gen_ref_kubric/${s}/metadata.json ${out}/${s}/metadata.json)
      endforeach()
    endif()
    require_no_leftovers(${out})
  endforeach()
endforeach()
message(STATUS "ok: generate killed mid-write (jobs and parent) resumes to the same dataset")

# The parent alone, at a moment while its jobs run: they must die with it (otherwise they race
# the resumed run for the same scenes), and the resumed run must still produce the same data.
foreach(delay 0.3 0.8)
  set(out ${WORK}/gen_timed_${delay})
  execute_process(COMMAND timeout --foreground -s KILL ${delay} ${HOPNET} ${gen} --format topos --out ${out} RESULT_VARIABLE rc OUTPUT_QUIET ERROR_QUIET)
  run(0 ${gen} --format topos --out ${out})
  if(NOT RC EQUAL 0)
    message(FATAL_ERROR "resuming generate after a kill at ${delay} s failed:\n${OUT}")
  endif()
  foreach(f dataset.json positions.npy quaternions.npy)
    require_same("generate killed at ${delay} s, resumed" ${WORK}/gen_ref/${f} ${out}/${f})
  endforeach()
  require_no_leftovers(${out})
endforeach()
message(STATUS "ok: generate with its parent killed resumes to the same dataset")

# ---- train ---------------------------------------------------------------------------------
file(WRITE ${WORK}/split.json "{\"train\": [1, 2, 3], \"val\": [4], \"test\": []}")
set(train train --data ${WORK}/gen_ref --split-file ${WORK}/split.json --hidden 8 --mode native --epochs 3 --seed 5 --max-frames 12)
run(0 ${train} --out ${WORK}/train_ref)
if(NOT RC EQUAL 0)
  message(FATAL_ERROR "uninterrupted train failed:\n${OUT}")
endif()
file(STRINGS ${WORK}/train_ref/steps.csv ref_steps)

# Compares a resumed run with the reference: the checkpoint bytes, and the logged losses row
# for row (epoch, step, scene, loss; the timings differ).
function(check_train out what)
  require_same("${what}" ${WORK}/train_ref/checkpoint.pt ${out}/checkpoint.pt)
  require_same("${what} (optimizer)" ${WORK}/train_ref/optimizer.pt ${out}/optimizer.pt)
  file(STRINGS ${out}/steps.csv steps)
  list(LENGTH steps n)
  list(LENGTH ref_steps nref)
  if(NOT n EQUAL nref)
    message(FATAL_ERROR "${what}: steps.csv has ${n} lines, the uninterrupted run's ${nref}")
  endif()
  foreach(i RANGE 1 ${n})
    if(i EQUAL n)
      break()
    endif()
    list(GET steps ${i} row)
    list(GET ref_steps ${i} ref)
    string(REGEX MATCH "^[^,]*,[^,]*,[^,]*,[^,]*" row "${row}")
    string(REGEX MATCH "^[^,]*,[^,]*,[^,]*,[^,]*" ref "${ref}")
    if(NOT row STREQUAL ref)
      message(FATAL_ERROR "${what}: steps.csv row ${i} is '${row}', the uninterrupted run logged '${ref}'")
    endif()
  endforeach()
  file(STRINGS ${out}/epochs.csv epochs)
  list(LENGTH epochs ne)
  if(NOT ne EQUAL 4)
    message(FATAL_ERROR "${what}: epochs.csv has ${ne} lines, want 4")
  endif()
  require_no_leftovers(${out})
endfunction()

# Crash points of a run: 1 stats.json; per epoch checkpoint.pt.next, optimizer.pt.next,
# state.json.next (halfway through each), the journal, then after each of the three renames.
# Points 2-8 hit every step of the first commit; 11 and 13 the second epoch's.
foreach(point 1 2 3 4 5 6 7 8 11 13)
  set(out ${WORK}/train_${point})
  run(${point} ${train} --out ${out})
  if(RC EQUAL 0)
    message(FATAL_ERROR "train with crash point ${point} was not killed:\n${OUT}")
  endif()
  run(0 ${train} --out ${out} --resume)
  if(NOT RC EQUAL 0)
    message(FATAL_ERROR "resuming train after crash point ${point} failed:\n${OUT}")
  endif()
  check_train(${out} "train killed at point ${point}, resumed")
endforeach()

# Killed again and again at the same point of every run (after stats and a whole commit, the
# next epoch's checkpoint write): each resumed run gets one epoch further.
set(out ${WORK}/train_repeated)
run(9 ${train} --out ${out})
foreach(attempt RANGE 1 6)
  run(9 ${train} --out ${out} --resume)
  if(RC EQUAL 0)
    break()
  endif()
endforeach()
if(NOT RC EQUAL 0)
  message(FATAL_ERROR "train killed at every run's point 9 never finished:\n${OUT}")
endif()
check_train(${out} "train killed repeatedly, resumed each time")

# At a moment mid-epoch (wherever the kill lands, the resumed run must match).
foreach(delay 1.5 3)
  set(out ${WORK}/train_timed_${delay})
  execute_process(COMMAND timeout --foreground -s KILL ${delay} ${HOPNET} ${train} --out ${out} RESULT_VARIABLE rc OUTPUT_QUIET ERROR_QUIET)
  run(0 ${train} --out ${out} --resume)
  if(NOT RC EQUAL 0)
    message(FATAL_ERROR "resuming train after a kill at ${delay} s failed:\n${OUT}")
  endif()
  check_train(${out} "train killed at ${delay} s, resumed")
endforeach()
message(STATUS "ok: train killed at every commit step and mid-epoch resumes to the same checkpoint")
