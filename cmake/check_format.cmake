# ctest house_format: every C++ source of the repository is clang-format clean (.clang-format:
# Google base, 100 columns). Skipped (the test's SKIP_REGULAR_EXPRESSION "format not checked")
# when the clang-format at hand is not the major version the tree is formatted with (another
# version formats some constructs otherwise).
# Usage: cmake -DSOURCE_DIR=<repo> -DCLANG_FORMAT=<exe> -DMAJOR=<n> -P cmake/check_format.cmake
cmake_minimum_required(VERSION 3.25)
if(NOT CLANG_FORMAT)
  message("clang-format ${MAJOR} not found: format not checked")
  return()
endif()
execute_process(COMMAND ${CLANG_FORMAT} --version OUTPUT_VARIABLE version)
if(NOT version MATCHES "version ${MAJOR}\\.")
  message("${CLANG_FORMAT} is not version ${MAJOR} (${version}): format not checked")
  return()
endif()
set(sources)
foreach(dir core session capture heightfield calibration maps brdf render assets sim app tests
            bench fuzz)
  file(GLOB_RECURSE found ${SOURCE_DIR}/${dir}/*.cc ${SOURCE_DIR}/${dir}/*.h)
  list(APPEND sources ${found})
endforeach()
list(LENGTH sources n)
if(n LESS 100)
  message(FATAL_ERROR "only ${n} sources found under ${SOURCE_DIR}")
endif()
execute_process(COMMAND ${CLANG_FORMAT} --dry-run --Werror ${sources}
                WORKING_DIRECTORY ${SOURCE_DIR} RESULT_VARIABLE rc ERROR_VARIABLE err)
if(NOT rc EQUAL 0)
  message("${err}")
  message(FATAL_ERROR "clang-format: the files above are not formatted (clang-format -i FILE)")
endif()
message(STATUS "${n} sources clang-format clean")
