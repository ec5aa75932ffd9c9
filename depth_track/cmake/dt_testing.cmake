# Test registration for both packages (depth_track's core and rig_drivers' ROS-free code), in
# one place. Included by depth_track/src/core/CMakeLists.txt and rig_drivers/src/CMakeLists.txt.
#
#   dt_testing_enabled(<var>)   sets <var> to ON when tests are to be declared:
#       catkin build: CATKIN_ENABLE_TESTING (catkin forbids catkin_add_gtest when it is off);
#       standalone build (plain cmake): DT_BUILD_TESTS, ON unless set OFF.
#   dt_add_gtest(<name> SOURCES ... [LIBS ...] [DEFINITIONS ...])
#       declares one gtest executable when testing is enabled, and nothing otherwise. A test that
#       cannot be declared (GoogleTest missing) stops the configure rather than vanish silently.
include_guard(GLOBAL)

option(DT_BUILD_TESTS "Declare the gtests in a standalone (non-catkin) build" ON)

function(dt_testing_enabled out)
  if(COMMAND catkin_add_gtest)
    if(CATKIN_ENABLE_TESTING)
      set(${out} ON PARENT_SCOPE)
    else()
      set(${out} OFF PARENT_SCOPE)
    endif()
  else()
    set(${out} ${DT_BUILD_TESTS} PARENT_SCOPE)
  endif()
endfunction()

function(dt_add_gtest name)
  cmake_parse_arguments(T "" "" "SOURCES;LIBS;DEFINITIONS" ${ARGN})
  dt_testing_enabled(enabled)
  if(NOT enabled)
    return()
  endif()
  if(COMMAND catkin_add_gtest)
    catkin_add_gtest(${name} ${T_SOURCES})
    if(NOT TARGET ${name})
      message(FATAL_ERROR "gtest ${name}: catkin could not declare it (is GoogleTest installed? "
                          "Debian: googletest libgtest-dev)")
    endif()
  else()
    find_package(GTest REQUIRED)
    add_executable(${name} ${T_SOURCES})
    target_link_libraries(${name} GTest::gtest)
    add_test(NAME ${name} COMMAND ${name})
  endif()
  target_link_libraries(${name} ${T_LIBS})
  target_compile_options(${name} PRIVATE -Wall -Wextra)
  if(T_DEFINITIONS)
    target_compile_definitions(${name} PRIVATE ${T_DEFINITIONS})
  endif()
endfunction()
