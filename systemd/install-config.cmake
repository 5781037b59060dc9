# Run by cmake --install (install(SCRIPT) in systemd/CMakeLists.txt, after
# install(CODE) has set MARKERD_CONFIG_SOURCE and MARKERD_CONFIG_DIR): copies
# the example config (config/: *.toml, *.yaml, README.md, subdirectories kept)
# into MARKERD_CONFIG_DIR under DESTDIR. A file that is already there is
# kept: it is the rig's own config, and reinstalling after a rebuild must not
# put the examples back over it. A packager installs into an empty DESTDIR and
# gets every file.
file(GLOB_RECURSE examples RELATIVE "${MARKERD_CONFIG_SOURCE}"
  "${MARKERD_CONFIG_SOURCE}/*.toml" "${MARKERD_CONFIG_SOURCE}/*.yaml" "${MARKERD_CONFIG_SOURCE}/README.md")
list(SORT examples)
foreach(example IN LISTS examples)
  set(destination "$ENV{DESTDIR}${MARKERD_CONFIG_DIR}/${example}")
  if(EXISTS "${destination}")
    message(STATUS "Keeping: ${destination}")
    continue()
  endif()
  get_filename_component(subdirectory "${MARKERD_CONFIG_DIR}/${example}" DIRECTORY)
  file(INSTALL DESTINATION "${subdirectory}" TYPE FILE FILES "${MARKERD_CONFIG_SOURCE}/${example}")
endforeach()
