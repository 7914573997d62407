# assemble.cmake - puts the viewer together in one directory that clothd serves at /:
#   cmake -DSRC=<repo>/web -DPROTO=<repo>/proto -DOUT=<build>/web [-DCLIENT=<repo>/clients/js] \
#         -P assemble.cmake
# The page's own files (index.html, style.css, src/*.js) are copied as they are; the npm packages
# of web/package-lock.json (installed by scripts/setup.sh: npm ci in web/) are copied to vendor/,
# the JavaScript client (CLIENT, by default clients/js beside web/), with the frame and recording
# decoders it holds (frame.mjs, delta-wasm.mjs, recording.mjs), to clients/js/src/, and proto/'s
# frame.mjs and recording.mjs (which re-export those) to proto/. index.html's import map names
# these paths; @mcap/core (its ES modules, with @foxglove/crc and heap-js) and @foxglove/schemas'
# JSON Schemas (CommonJS, wrapped below as an ES module) serve the MCAP export, webm-muxer the
# WebM video of a recording's range. No bundler: the browser loads ES modules, nothing comes from
# a CDN. Without web/node_modules the page cannot work, so nothing is assembled and clothd serves
# its placeholder page.
set(vendor
  "three/build/three.module.js" "three.module.js"
  "three/build/three.core.js" "three.core.js"
  "three/examples/jsm/controls/OrbitControls.js" "OrbitControls.js"
  "three/examples/jsm/exporters/GLTFExporter.js" "GLTFExporter.js"
  "three/examples/jsm/exporters/PLYExporter.js" "PLYExporter.js"
  "lil-gui/dist/lil-gui.esm.js" "lil-gui.esm.js"
  "uplot/dist/uPlot.esm.js" "uPlot.esm.js"
  "uplot/dist/uPlot.min.css" "uPlot.min.css"
  "meshoptimizer/meshopt_decoder.mjs" "meshopt_decoder.mjs"
  "zstddec/dist/zstddec.mjs" "zstddec.mjs"
  "webm-muxer/build/webm-muxer.mjs" "webm-muxer.mjs"
  "heap-js/dist/heap-js.es5.js" "heap-js.js"
  "@foxglove/crc/dist/esm/src/index.js" "foxglove-crc.js"
  "@mcap/core/dist/esm/index.js" "mcap-core/index.js"
  "@foxglove/schemas/dist/jsonschema/index.js" "foxglove-schemas-jsonschema.cjs"
  "three/LICENSE" "LICENSE.three"
  "lil-gui/LICENSE.md" "LICENSE.lil-gui"
  "uplot/LICENSE" "LICENSE.uplot"
  "meshoptimizer/LICENSE.md" "LICENSE.meshoptimizer"
  "zstddec/LICENSE" "LICENSE.zstddec"
  "webm-muxer/LICENSE" "LICENSE.webm-muxer"
  "heap-js/LICENSE" "LICENSE.heap-js"
  "@foxglove/crc/LICENSE.md" "LICENSE.foxglove-crc"
  "@mcap/core/LICENSE" "LICENSE.mcap-core")

foreach(v SRC PROTO OUT)
  if(NOT DEFINED ${v})
    message(FATAL_ERROR "assemble.cmake needs -D${v}=...")
  endif()
endforeach()

set(missing "")
list(LENGTH vendor n)
math(EXPR last "${n} - 1")
foreach(i RANGE 0 ${last} 2)
  list(GET vendor ${i} from)
  if(NOT EXISTS "${SRC}/node_modules/${from}")
    list(APPEND missing "${from}")
  endif()
endforeach()
if(NOT DEFINED CLIENT)
  get_filename_component(CLIENT "${SRC}/../clients/js" ABSOLUTE)
endif()
if(NOT EXISTS "${CLIENT}/src/index.js")
  message(FATAL_ERROR "assemble.cmake: no JavaScript client at ${CLIENT} (-DCLIENT=<repo>/clients/js)")
endif()
if(missing)
  message(WARNING "viewer not assembled: web/node_modules lacks ${missing} (run scripts/setup.sh, "
                  "or npm ci in web/); clothd serves a placeholder page at /")
  file(REMOVE_RECURSE "${OUT}")
  return()
endif()

file(REMOVE_RECURSE "${OUT}/src" "${OUT}/clients" "${OUT}/proto") # a file removed from web/ or clients/js goes from here too
file(MAKE_DIRECTORY "${OUT}/vendor" "${OUT}/vendor/mcap-core" "${OUT}/proto" "${OUT}/src" "${OUT}/clients/js/src")
file(GLOB page RELATIVE "${SRC}" "${SRC}/*.html" "${SRC}/*.css" "${SRC}/src/*.js")
foreach(f ${page})
  file(COPY_FILE "${SRC}/${f}" "${OUT}/${f}" ONLY_IF_DIFFERENT)
endforeach()
foreach(i RANGE 0 ${last} 2)
  list(GET vendor ${i} from)
  math(EXPR j "${i} + 1")
  list(GET vendor ${j} to)
  file(COPY_FILE "${SRC}/node_modules/${from}" "${OUT}/vendor/${to}" ONLY_IF_DIFFERENT)
endforeach()
# @mcap/core (the MCAP export): its ES modules, without its tests. @foxglove/schemas' JSON
# Schemas are CommonJS (assignments to `exports`, nothing required): wrapped here as an ES module.
file(GLOB mcap RELATIVE "${SRC}/node_modules/@mcap/core/dist/esm" "${SRC}/node_modules/@mcap/core/dist/esm/*.js")
list(FILTER mcap EXCLUDE REGEX "(\\.test\\.js|testUtils\\.js)$")
foreach(f ${mcap})
  file(COPY_FILE "${SRC}/node_modules/@mcap/core/dist/esm/${f}" "${OUT}/vendor/mcap-core/${f}" ONLY_IF_DIFFERENT)
endforeach()
file(READ "${OUT}/vendor/foxglove-schemas-jsonschema.cjs" schemas)
file(REMOVE "${OUT}/vendor/foxglove-schemas-jsonschema.cjs")
file(WRITE "${OUT}/vendor/foxglove-schemas-jsonschema.js.new"
  "// @foxglove/schemas/jsonschema (MIT), its CommonJS as an ES module (web/assemble.cmake)\n"
  "const exports = {};\n${schemas}\nexport default exports;\nexport const { SceneUpdate } = exports;\n")
file(COPY_FILE "${OUT}/vendor/foxglove-schemas-jsonschema.js.new" "${OUT}/vendor/foxglove-schemas-jsonschema.js" ONLY_IF_DIFFERENT)
file(REMOVE "${OUT}/vendor/foxglove-schemas-jsonschema.js.new")
foreach(f frame.mjs recording.mjs)
  file(COPY_FILE "${PROTO}/${f}" "${OUT}/proto/${f}" ONLY_IF_DIFFERENT)
endforeach()
file(GLOB client RELATIVE "${CLIENT}/src" "${CLIENT}/src/*.js" "${CLIENT}/src/*.mjs")
foreach(f ${client})
  file(COPY_FILE "${CLIENT}/src/${f}" "${OUT}/clients/js/src/${f}")
endforeach()
