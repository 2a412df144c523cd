# One static library per layer (see the top-level CMakeLists.txt).
#
#   vkunroll_layer(<name> DIR <dir> [EXTRA_SOURCES ...] [PUBLIC deps...] [PRIVATE deps...]
#                  [PRIVATE_INCLUDES dirs...])
# builds vkunroll_<name> from <dir>/*.cpp (exported as vkunroll::<name>), with the build-tree include
# root include/<name>/vkunroll/<dir> -> <dir>, and records <dir>'s public headers for installation
# (every .hpp except *_detail.hpp, which are private to the layer's sources).

set(VKUNROLL_LAYERS "" CACHE INTERNAL "")

function(vkunroll_include_root root dir)
  set(link ${root}/vkunroll/${dir})
  get_filename_component(parent ${link} DIRECTORY)
  file(MAKE_DIRECTORY ${parent})
  if(NOT IS_SYMLINK ${link})
    file(CREATE_LINK ${PROJECT_SOURCE_DIR}/${dir} ${link} SYMBOLIC)
  endif()
endfunction()

# A private include root for an executable's own headers (host/cli).
function(vkunroll_private_root target dir)
  set(root ${PROJECT_BINARY_DIR}/include/${target})
  vkunroll_include_root(${root} ${dir})
  target_include_directories(${target} PRIVATE ${root})
endfunction()

function(vkunroll_layer name)
  cmake_parse_arguments(L "" "DIR" "EXTRA_SOURCES;PUBLIC;PRIVATE;PRIVATE_INCLUDES" ${ARGN})
  set(target vkunroll_${name})
  file(GLOB sources CONFIGURE_DEPENDS ${PROJECT_SOURCE_DIR}/${L_DIR}/*.cpp)
  add_library(${target} STATIC ${sources} ${L_EXTRA_SOURCES})
  set(root ${PROJECT_BINARY_DIR}/include/${name})
  vkunroll_include_root(${root} ${L_DIR})
  target_include_directories(${target}
    PUBLIC $<BUILD_INTERFACE:${root}> $<INSTALL_INTERFACE:${CMAKE_INSTALL_INCLUDEDIR}>
    PRIVATE ${L_PRIVATE_INCLUDES})
  target_link_libraries(${target} PUBLIC ${L_PUBLIC} PRIVATE ${L_PRIVATE})
  target_compile_options(${target} PRIVATE ${VKUNROLL_WARNINGS})
  target_compile_definitions(${target} PRIVATE VKUNROLL_SOURCE_DIR="${PROJECT_SOURCE_DIR}")
  set_target_properties(${target} PROPERTIES POSITION_INDEPENDENT_CODE ON EXPORT_NAME ${name})
  add_library(vkunroll::${name} ALIAS ${target})
  set(VKUNROLL_LAYERS ${VKUNROLL_LAYERS} ${name} CACHE INTERNAL "")
  set_property(GLOBAL PROPERTY VKUNROLL_LAYER_DIR_${name} ${L_DIR})
endfunction()

# Installs every layer's library and public headers (include/vkunroll/<dir>/), one export set per
# layer, and the package config that loads only the requested components and their dependencies.
function(vkunroll_install_layers)
  install(TARGETS vkunroll_volk EXPORT vkunroll_volk_targets ARCHIVE DESTINATION ${CMAKE_INSTALL_LIBDIR})
  install(EXPORT vkunroll_volk_targets NAMESPACE vkunroll:: DESTINATION ${CMAKE_INSTALL_LIBDIR}/cmake/vkunroll)
  foreach(name ${VKUNROLL_LAYERS})
    get_property(dir GLOBAL PROPERTY VKUNROLL_LAYER_DIR_${name})
    install(TARGETS vkunroll_${name} EXPORT vkunroll_${name}_targets ARCHIVE DESTINATION ${CMAKE_INSTALL_LIBDIR})
    install(EXPORT vkunroll_${name}_targets NAMESPACE vkunroll:: DESTINATION ${CMAKE_INSTALL_LIBDIR}/cmake/vkunroll)
    file(GLOB headers CONFIGURE_DEPENDS ${PROJECT_SOURCE_DIR}/${dir}/*.hpp)
    list(FILTER headers EXCLUDE REGEX "_detail\\.hpp$")
    install(FILES ${headers} DESTINATION ${CMAKE_INSTALL_INCLUDEDIR}/vkunroll/${dir})
  endforeach()
  install(TARGETS vkunroll EXPORT vkunroll_all_targets)
  install(EXPORT vkunroll_all_targets NAMESPACE vkunroll:: DESTINATION ${CMAKE_INSTALL_LIBDIR}/cmake/vkunroll)
  include(CMakePackageConfigHelpers)
  configure_package_config_file(${PROJECT_SOURCE_DIR}/cmake/vkunrollConfig.cmake.in
    ${PROJECT_BINARY_DIR}/vkunrollConfig.cmake
    INSTALL_DESTINATION ${CMAKE_INSTALL_LIBDIR}/cmake/vkunroll)
  write_basic_package_version_file(${PROJECT_BINARY_DIR}/vkunrollConfigVersion.cmake
    COMPATIBILITY SameMajorVersion)
  install(FILES ${PROJECT_BINARY_DIR}/vkunrollConfig.cmake ${PROJECT_BINARY_DIR}/vkunrollConfigVersion.cmake
                ${PROJECT_SOURCE_DIR}/cmake/OpenCVModules.cmake
    DESTINATION ${CMAKE_INSTALL_LIBDIR}/cmake/vkunroll)
endfunction()
