# ctest install.python: `cmake --install --component python` into an empty prefix, then import the
# package from there with Debian's Python (and not from the build tree), list the devices, and find
# the default model installed under the prefix (not the source tree's).
file(REMOVE_RECURSE ${PREFIX})
execute_process(COMMAND ${CMAKE_COMMAND} --install ${BUILD} --prefix ${PREFIX} --component python
                RESULT_VARIABLE rc)
if(NOT rc EQUAL 0)
  message(FATAL_ERROR "cmake --install --component python failed (${rc})")
endif()
set(site ${PREFIX}/${SITE})
execute_process(
  COMMAND ${CMAKE_COMMAND} -E env PYTHONPATH=${site} PYTHONNOUSERSITE=1
          ${PYTHON} -c "import vkunroll, os, sys; assert os.path.realpath(vkunroll.__file__).startswith(os.path.realpath(sys.argv[1])), vkunroll.__file__; d = vkunroll.devices(); assert d and all('name' in x for x in d), d; m = vkunroll.default_model(); assert m and os.path.realpath(m).startswith(os.path.realpath(sys.argv[2])), m; print(vkunroll.__file__, m, d[0]['name'], d[0]['api_version'])" ${site} ${PREFIX}/share/vkunroll/models
  WORKING_DIRECTORY ${PREFIX}
  RESULT_VARIABLE rc OUTPUT_VARIABLE out ERROR_VARIABLE err)
message(STATUS "${out}${err}")
if(NOT rc EQUAL 0)
  message(FATAL_ERROR "import vkunroll from ${site} failed (${rc})")
endif()
