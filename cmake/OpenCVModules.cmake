# OpenCV's four modules that vkunroll links: core, imgproc, imgcodecs, videoio.
# Debian keeps OpenCVConfig.cmake in libopencv-dev, which depends on every module (VTK, dnn, viz:
# about 400 MB more). With only libopencv-{core,imgproc,imgcodecs,videoio}-dev installed, the four
# libraries are found directly and given the targets OpenCVConfig.cmake would have made.
# Included by the build and by the installed vkunrollConfig.cmake.
if(TARGET opencv_core AND TARGET opencv_imgproc AND TARGET opencv_imgcodecs AND TARGET opencv_videoio)
  return()
endif()
find_package(OpenCV QUIET COMPONENTS core imgproc imgcodecs videoio)
if(OpenCV_FOUND)
  return()
endif()
find_path(VKUNROLL_OPENCV_INCLUDE_DIR opencv2/core.hpp PATH_SUFFIXES opencv4)
find_path(VKUNROLL_OPENCV_ARCH_INCLUDE_DIR opencv2/cvconfig.h
  PATHS /usr/include/${CMAKE_LIBRARY_ARCHITECTURE} PATH_SUFFIXES opencv4)
if(NOT VKUNROLL_OPENCV_INCLUDE_DIR)
  message(FATAL_ERROR "OpenCV not found: install libopencv-core-dev libopencv-imgproc-dev "
                      "libopencv-imgcodecs-dev libopencv-videoio-dev (or libopencv-dev)")
endif()
set(_vkunroll_cv_includes ${VKUNROLL_OPENCV_INCLUDE_DIR})
if(VKUNROLL_OPENCV_ARCH_INCLUDE_DIR)
  list(APPEND _vkunroll_cv_includes ${VKUNROLL_OPENCV_ARCH_INCLUDE_DIR})
endif()
foreach(_m core imgproc imgcodecs videoio)
  find_library(VKUNROLL_OPENCV_${_m}_LIBRARY opencv_${_m})
  if(NOT VKUNROLL_OPENCV_${_m}_LIBRARY)
    message(FATAL_ERROR "OpenCV's ${_m} library (libopencv_${_m}.so) not found: install libopencv-${_m}-dev")
  endif()
  add_library(opencv_${_m} SHARED IMPORTED GLOBAL)
  set_target_properties(opencv_${_m} PROPERTIES
    IMPORTED_LOCATION ${VKUNROLL_OPENCV_${_m}_LIBRARY}
    INTERFACE_INCLUDE_DIRECTORIES "${_vkunroll_cv_includes}")
endforeach()
set_property(TARGET opencv_imgproc APPEND PROPERTY INTERFACE_LINK_LIBRARIES opencv_core)
set_property(TARGET opencv_imgcodecs APPEND PROPERTY INTERFACE_LINK_LIBRARIES opencv_imgproc opencv_core)
set_property(TARGET opencv_videoio APPEND PROPERTY INTERFACE_LINK_LIBRARIES opencv_imgcodecs opencv_core)
set(OpenCV_FOUND TRUE)
message(STATUS "OpenCV: core, imgproc, imgcodecs, videoio found directly (${VKUNROLL_OPENCV_INCLUDE_DIR})")
