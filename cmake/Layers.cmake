# One static library per layer (see the top-level CMakeLists.txt).
#
#   vkunroll_layer(<name> DIR <dir> [VULKAN_FREE] [EXTRA_SOURCES ...] [PUBLIC deps...] [PRIVATE deps...]
#                  [PRIVATE_INCLUDES dirs...])
# builds vkunroll_<name> from <dir>/*.cpp (exported as vkunroll::<name>), with the build-tree include
# root include/<name>/vkunroll/<dir> -> <dir>, and records <dir>'s public headers for installation
# (every .hpp except *_detail.hpp, which are private to the layer's sources). VULKAN_FREE: a Vulkan
# header (vulkan/*, vk_video/*, volk.h) included by the layer's sources or headers fails to compile.

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

# An include root that shadows every Vulkan header with one that is an #error: first on a Vulkan-free
# layer's include path, it is found before the real headers (which sit in the system include path).
function(vkunroll_vulkan_poison_root out)
  set(root ${PROJECT_BINARY_DIR}/include/vulkan_free)
  file(GLOB vulkan_headers RELATIVE ${Vulkan_INCLUDE_DIRS} ${Vulkan_INCLUDE_DIRS}/vulkan/* ${Vulkan_INCLUDE_DIRS}/vk_video/*)
  foreach(header ${vulkan_headers} volk.h)
    file(CONFIGURE OUTPUT ${root}/${header} CONTENT
      "#error \"${header} included in a Vulkan-free layer (base, events, sim): Vulkan belongs in runtime/ and the layers above it\"\n")
  endforeach()
  set(${out} ${root} PARENT_SCOPE)
endfunction()

# A source that includes every header of <dir>, so that a header no source of the layer includes is
# compiled with the layer's include path too (and its Vulkan-free rule).
function(vkunroll_all_headers_source out name dir)
  file(GLOB headers CONFIGURE_DEPENDS RELATIVE ${PROJECT_SOURCE_DIR} ${PROJECT_SOURCE_DIR}/${dir}/*.hpp)
  set(content "// Generated (cmake/Layers.cmake): every header of ${dir}, compiled as part of vkunroll_${name}.\n")
  foreach(header ${headers})
    string(APPEND content "#include \"vkunroll/${header}\"\n")
  endforeach()
  set(src ${PROJECT_BINARY_DIR}/generated/all_headers_${name}.cpp)
  file(CONFIGURE OUTPUT ${src} CONTENT "${content}")
  set(${out} ${src} PARENT_SCOPE)
endfunction()

function(vkunroll_layer name)
  cmake_parse_arguments(L "VULKAN_FREE" "DIR" "EXTRA_SOURCES;PUBLIC;PRIVATE;PRIVATE_INCLUDES" ${ARGN})
  set(target vkunroll_${name})
  file(GLOB sources CONFIGURE_DEPENDS ${PROJECT_SOURCE_DIR}/${L_DIR}/*.cpp)
  add_library(${target} STATIC ${sources} ${L_EXTRA_SOURCES})
  set(root ${PROJECT_BINARY_DIR}/include/${name})
  vkunroll_include_root(${root} ${L_DIR})
  target_include_directories(${target}
    PUBLIC $<BUILD_INTERFACE:${root}> $<INSTALL_INTERFACE:${CMAKE_INSTALL_INCLUDEDIR}>
    PRIVATE ${L_PRIVATE_INCLUDES})
  target_link_libraries(${target} PUBLIC ${L_PUBLIC} PRIVATE ${L_PRIVATE})
  if(L_VULKAN_FREE)
    vkunroll_vulkan_poison_root(poison)
    vkunroll_all_headers_source(all_headers ${name} ${L_DIR})
    target_sources(${target} PRIVATE ${all_headers})
    target_include_directories(${target} BEFORE PRIVATE ${poison})
  endif()
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
