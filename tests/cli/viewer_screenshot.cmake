# Opens the pages written by the hopnet_pipeline test in headless Chromium, offline: the rollout
# viewer (three.js must draw both views, its status line counts the triangles drawn, and its
# Chart.js error curve must be drawn), the evaluation report index.html and the training curves
# training.html (every Chart.js plot drawn: the page counts them in <body data-charts>). Each
# page must also come out as a screenshot. Arguments: -DCHROMIUM=<exe or empty>
# -DPIPELINE=<the pipeline test's folder> -DWORK=<dir>.
if(NOT CHROMIUM)
  message("SKIPPED: Debian's chromium is not installed (scripts/setup.sh installs it for the test suite)")
  return()
endif()
set(viewer ${PIPELINE}/eval/viewer.html)
set(report ${PIPELINE}/eval/index.html)
set(training ${PIPELINE}/model/training.html)
foreach(page ${viewer} ${report} ${training})
  if(NOT EXISTS ${page})
    message(FATAL_ERROR "no page at ${page} (the hopnet_pipeline test writes it)")
  endif()
endforeach()
file(MAKE_DIRECTORY ${WORK})
# WebGL in software (SwiftShader): no GPU here, and Chromium no longer falls back by itself. No
# network: the pages must need none.
set(flags --headless --no-sandbox --disable-gpu --enable-unsafe-swiftshader --use-angle=swiftshader
  --disable-background-networking --disable-component-update --no-first-run --hide-scrollbars
  --user-data-dir=${WORK}/profile)

# One Chromium run per page: the DOM once its scripts have run, and a screenshot.
function(open_page url size png out)
  file(REMOVE ${png})
  execute_process(COMMAND ${CHROMIUM} ${flags} --window-size=${size} --dump-dom --screenshot=${png} "${url}"
    RESULT_VARIABLE rc OUTPUT_VARIABLE dom ERROR_VARIABLE err TIMEOUT 180)
  if(NOT rc EQUAL 0 OR NOT EXISTS ${png})
    message(FATAL_ERROR "chromium on ${url} failed (${rc}):\n${err}")
  endif()
  file(READ ${png} head LIMIT 8 HEX)
  file(SIZE ${png} bytes)
  if(NOT head STREQUAL "89504e470d0a1a0a" OR bytes LESS 20000)
    message(FATAL_ERROR "the screenshot ${png} is not a plausible PNG (${bytes} bytes)")
  endif()
  message(STATUS "screenshot ${png} (${bytes} bytes)")
  set(${out} "${dom}" PARENT_SCOPE)
endfunction()

function(require_charts dom page want)
  string(REGEX MATCH "<body[^>]* data-charts=\"([0-9]+)\"" m "${dom}")
  if(NOT m OR CMAKE_MATCH_1 LESS want)
    message(FATAL_ERROR "${page}: its script did not draw its ${want} plots (${m}):\n${dom}")
  endif()
endfunction()

# The viewer, side by side and overlaid.
foreach(mode side overlay)
  open_page("file://${viewer}?frame=20&mode=${mode}" 1400,860 ${WORK}/viewer_${mode}.png dom)
  string(REGEX MATCH "id=\"status\">([0-9]+) objects, ([0-9]+) triangles drawn" m "${dom}")
  if(NOT m)
    message(FATAL_ERROR "the viewer's script did not render (no status line in the DOM):\n${dom}")
  endif()
  if(CMAKE_MATCH_1 LESS 1 OR CMAKE_MATCH_2 LESS 100)
    message(FATAL_ERROR "the viewer drew too little: ${m}")
  endif()
  string(FIND "${dom}" "frame 20 / " pos)
  if(pos EQUAL -1)
    message(FATAL_ERROR "the viewer did not go to the frame asked for in the URL")
  endif()
  require_charts("${dom}" viewer 1)
  message(STATUS "ok: viewer (${mode}): ${m}")
endforeach()

# The report: three error plots and, from the checkpoint's logs, two training plots.
open_page("file://${report}" 1280,3000 ${WORK}/report.png dom)
require_charts("${dom}" index.html 5)
string(FIND "${dom}" "Rollout error at the paper's horizons" pos)
if(pos EQUAL -1)
  message(FATAL_ERROR "index.html did not build its tables")
endif()
message(STATUS "ok: index.html")

open_page("file://${training}" 1280,1000 ${WORK}/training.png dom)
require_charts("${dom}" training.html 2)
message(STATUS "ok: training.html")
