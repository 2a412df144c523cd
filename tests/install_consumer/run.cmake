# ctest: install vkunroll into a temporary prefix, then build and run two consumers with
# find_package(vkunroll): the whole package (examples/cpp, an UnrollJob over a sequence folder with
# the installed default model), and the runtime layer alone with OpenCV, HDF5 and the compression
# libraries made unfindable.
file(REMOVE_RECURSE ${WORK})
execute_process(COMMAND ${CMAKE_COMMAND} --install ${BUILD} --prefix ${WORK}/prefix RESULT_VARIABLE r OUTPUT_QUIET)
if(r)
  message(FATAL_ERROR "cmake --install failed: ${r}")
endif()
# Only public headers are installed, under include/vkunroll/.
file(GLOB_RECURSE detail ${WORK}/prefix/include/*_detail.hpp)
if(detail)
  message(FATAL_ERROR "internal headers were installed: ${detail}")
endif()
if(NOT EXISTS ${WORK}/prefix/include/vkunroll/runtime/context.hpp)
  message(FATAL_ERROR "include/vkunroll/runtime/context.hpp was not installed")
endif()

# consumer(NAME SOURCE_DIR EXECUTABLE EXPECTED_OUTPUT_REGEX [CMAKE_ARGS ...] [RUN_ARGS ...])
function(consumer name src exe expect)
  cmake_parse_arguments(C "" "" "CMAKE_ARGS;RUN_ARGS" ${ARGN})
  execute_process(COMMAND ${CMAKE_COMMAND} -S ${src} -B ${WORK}/${name} -G Ninja -DCMAKE_PREFIX_PATH=${WORK}/prefix ${C_CMAKE_ARGS}
                  RESULT_VARIABLE r)
  if(r)
    message(FATAL_ERROR "configuring the ${name} consumer failed: ${r}")
  endif()
  execute_process(COMMAND ${CMAKE_COMMAND} --build ${WORK}/${name} RESULT_VARIABLE r)
  if(r)
    message(FATAL_ERROR "building the ${name} consumer failed: ${r}")
  endif()
  execute_process(COMMAND ${WORK}/${name}/${exe} ${C_RUN_ARGS} WORKING_DIRECTORY ${WORK} RESULT_VARIABLE r
                  OUTPUT_VARIABLE out ERROR_VARIABLE err)
  if(r OR NOT out MATCHES "${expect}")
    message(FATAL_ERROR "the ${name} consumer did not run as expected: exit ${r}\n${out}${err}")
  endif()
  message(STATUS "${name}: ${out}")
endfunction()

# The installed CLI, run from outside the source tree with no --model, runs the installed default model.
set(cli ${WORK}/prefix/bin/vkunroll)
execute_process(COMMAND ${cli} simulate --out ${WORK}/seq --preset clean --size 48x32 --frames 2 --gt-per-frame 1 --seed 3 --quiet
                WORKING_DIRECTORY ${WORK} RESULT_VARIABLE r ERROR_VARIABLE err)
if(r)
  message(FATAL_ERROR "the installed vkunroll simulate failed: ${r} ${err}")
endif()
execute_process(COMMAND ${cli} unroll ${WORK}/seq --out ${WORK}/unrolled --times 0.5 --frames 0 --quiet --no-video
                WORKING_DIRECTORY ${WORK} RESULT_VARIABLE r ERROR_VARIABLE err)
if(r)
  message(FATAL_ERROR "the installed vkunroll unroll (no --model) failed: ${r} ${err}")
endif()
file(READ ${WORK}/unrolled/summary.json summary)
string(JSON model_path GET "${summary}" model path)
string(JSON model_source GET "${summary}" model source)
file(REAL_PATH ${WORK}/prefix/share/vkunroll/models prefix_models)
string(FIND "${model_path}" "${prefix_models}/" at)
if(NOT at EQUAL 0 OR NOT model_source STREQUAL "default (installed)")
  message(FATAL_ERROR "the installed CLI ran ${model_path} (${model_source}), not the default model under ${prefix_models}")
endif()
message(STATUS "installed CLI, no --model: ${model_path} (${model_source})")

# The C++ example a user copies: two GS frames (one per RS frame, with ground truth there) from the
# default model. A program outside PREFIX/bin finds it in the prefix the library was configured
# with, else the source tree (host/unroll/default_model.hpp): here the source tree's, since this
# prefix is a temporary one; the installed CLI above shows the installed lookup.
consumer(example ${EXAMPLE} unroll_folder
  "frame 0 t=[0-9.]+ us: 48x32 GS image, PSNR [0-9.]+ dB against the ground truth\n.*\n2 GS frames, model [^\n]*/selfunroll_small_physics.safetensors \\(default \\("
  RUN_ARGS ${WORK}/seq gt)
consumer(runtime_only ${SRC}/runtime_only runtime_consumer "device"
  CMAKE_ARGS -DCMAKE_DISABLE_FIND_PACKAGE_OpenCV=ON -DCMAKE_DISABLE_FIND_PACKAGE_HDF5=ON
  -DCMAKE_DISABLE_FIND_PACKAGE_PkgConfig=ON -DCMAKE_DISABLE_FIND_PACKAGE_nlohmann_json=ON)
file(REMOVE_RECURSE ${WORK})
