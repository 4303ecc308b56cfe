# tetcosim_set_warnings(target): the project's warning set, kept private so
# that users of the libraries are not forced into it.
function(tetcosim_set_warnings target)
  target_compile_options(${target} PRIVATE
    -Wall -Wextra -Wpedantic -Wshadow -Wnon-virtual-dtor -Wcast-align
    -Woverloaded-virtual -Wnull-dereference -Wimplicit-fallthrough)
endfunction()

# tetcosim_add_library(name SOURCES ...): a library target tetcosim_<name>
# with the alias tetcosim::<name>, whose headers are included as
# "<folder>/<header>.h" from the repository root.
function(tetcosim_add_library name)
  cmake_parse_arguments(ARG "" "" "SOURCES" ${ARGN})
  add_library(tetcosim_${name} ${ARG_SOURCES})
  add_library(tetcosim::${name} ALIAS tetcosim_${name})
  target_include_directories(tetcosim_${name} PUBLIC ${PROJECT_SOURCE_DIR})
  target_compile_features(tetcosim_${name} PUBLIC cxx_std_20)
  tetcosim_set_warnings(tetcosim_${name})
endfunction()
