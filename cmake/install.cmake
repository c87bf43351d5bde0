# cmake --install build --prefix DIR: what a user of the tool and of the libraries gets.
#   bin/voxelastic, bin/voxelastic-probe            the programs
#   share/man/man1/voxelastic*.1                     man pages from --help (when help2man is found)
#   share/bash-completion/completions/voxelastic*    tab completion (bash)
#   lib/voxelastic/slicer-cli/voxelastic-convert     convert as a 3D Slicer CLI module (--xml)
#   include/voxelastic/{base,model,...,io,convert,...}/*.h   the core and pipeline headers
#   lib/libvoxelastic_core.a, lib/libvoxelastic_pipeline.a
#   lib/cmake/voxelastic/voxelastic-config.cmake     find_package(voxelastic): voxelastic::core, voxelastic::pipeline
# examples/find_package/ builds against such a tree; tests/install/ checks it (ctest -L install).
include(CMakePackageConfigHelpers)
set(VOXELASTIC_CMAKE_DIR ${CMAKE_INSTALL_LIBDIR}/cmake/voxelastic)

# the core: every header, and the generated version.h
set(_vx_libraries voxelastic_core)
install(DIRECTORY src/ DESTINATION ${CMAKE_INSTALL_INCLUDEDIR}/voxelastic FILES_MATCHING PATTERN "*.h")
install(FILES ${PROJECT_BINARY_DIR}/src/generated/base/version.h DESTINATION ${CMAKE_INSTALL_INCLUDEDIR}/voxelastic/base)

# the pipeline, when it is built; its headers but the three that include VTK (the readers'
# internals: a user reads and writes volumes through io/volume_io.h)
if(TARGET voxelastic_pipeline)
  list(APPEND _vx_libraries voxelastic_pipeline)
  install(DIRECTORY pipeline/ DESTINATION ${CMAKE_INSTALL_INCLUDEDIR}/voxelastic FILES_MATCHING PATTERN "*.h"
          PATTERN "vtk_messages.h" EXCLUDE PATTERN "vtk_arrays.h" EXCLUDE PATTERN "volume_formats.h" EXCLUDE)
endif()
install(TARGETS ${_vx_libraries} EXPORT voxelastic-targets
        ARCHIVE DESTINATION ${CMAKE_INSTALL_LIBDIR} LIBRARY DESTINATION ${CMAKE_INSTALL_LIBDIR})
install(EXPORT voxelastic-targets NAMESPACE voxelastic:: FILE voxelastic-targets.cmake DESTINATION ${VOXELASTIC_CMAKE_DIR})

# voxelastic-config.cmake finds what the libraries link (the static libraries' private
# dependencies too: VTK, DCMTK, ...), then the targets
if(TARGET voxelastic_pipeline)
  set(VOXELASTIC_CONFIG_HAS_PIPELINE ON)
else()
  set(VOXELASTIC_CONFIG_HAS_PIPELINE OFF)
endif()
configure_package_config_file(cmake/voxelastic-config.cmake.in ${PROJECT_BINARY_DIR}/voxelastic-config.cmake
                              INSTALL_DESTINATION ${VOXELASTIC_CMAKE_DIR})
write_basic_package_version_file(${PROJECT_BINARY_DIR}/voxelastic-config-version.cmake
                                 VERSION ${PROJECT_VERSION} COMPATIBILITY SameMinorVersion)
install(FILES ${PROJECT_BINARY_DIR}/voxelastic-config.cmake ${PROJECT_BINARY_DIR}/voxelastic-config-version.cmake
        DESTINATION ${VOXELASTIC_CMAKE_DIR})

# the programs, their completion and their man pages
if(VOXELASTIC_BUILD_APPS)
  install(TARGETS voxelastic voxelastic-probe RUNTIME DESTINATION ${CMAKE_INSTALL_BINDIR})
  install(FILES apps/voxelastic/completion.bash DESTINATION ${CMAKE_INSTALL_DATADIR}/bash-completion/completions
          RENAME voxelastic)
  install(FILES apps/voxelastic/completion.bash DESTINATION ${CMAKE_INSTALL_DATADIR}/bash-completion/completions
          RENAME voxelastic-probe)
  install(FILES LICENSE README.md DESTINATION ${CMAKE_INSTALL_DOCDIR})
  # convert as a 3D Slicer CLI module (`voxelastic convert --xml`): a one-line program in a
  # folder of its own, for Slicer's additional module paths
  set(_vx_slicer_dir ${CMAKE_INSTALL_LIBDIR}/voxelastic/slicer-cli)
  file(RELATIVE_PATH VOXELASTIC_BIN_FROM_SLICER /prefix/${_vx_slicer_dir} /prefix/${CMAKE_INSTALL_BINDIR})
  configure_file(apps/voxelastic/slicer/voxelastic-convert.in ${PROJECT_BINARY_DIR}/slicer-cli/voxelastic-convert @ONLY)
  install(PROGRAMS ${PROJECT_BINARY_DIR}/slicer-cli/voxelastic-convert DESTINATION ${_vx_slicer_dir})

  # man pages: help2man runs each program's --help (one page per voxelastic subcommand too)
  find_program(VOXELASTIC_HELP2MAN help2man)
  if(VOXELASTIC_HELP2MAN)
    set(_vx_man_dir ${PROJECT_BINARY_DIR}/man)
    set(_vx_pages)
    # each page: (help option, the page's one-line name)
    set(_vx_man_voxelastic "--help" "CT volumes to gradational-resolution elastic models")
    set(_vx_man_voxelastic-probe "--help" "palpate a soft-tissue model with a joystick and feel the force")
    set(_vx_man_voxelastic-phantom "phantom --help" "write a synthetic CT volume of a known shape")
    set(_vx_man_voxelastic-convert "convert --help" "convert a CT volume into a gradational-resolution elastic model")
    set(_vx_man_voxelastic-simulate "simulate --help" "run a scene headless: forces, summary, ParaView series")
    set(_vx_man_voxelastic-verify "verify --help" "run the verification suite on synthetic phantoms")
    set(_vx_man_voxelastic-verify-merge "verify-merge --help" "combine the reports of sharded verify runs")
    set(_vx_man_voxelastic-bench "bench --help" "benchmarks: the cost of a step, run time against error")
    set(_vx_man_voxelastic-palpate-map "palpate-map --help" "press a ball over a face and map the stiffness")
    set(_vx_man_voxelastic-plot "plot --help" "draw a plot described in JSON into a PNG")
    # one page per subcommand (tests/install/install_test.cmake checks against voxelastic --help)
    foreach(page voxelastic voxelastic-probe voxelastic-phantom voxelastic-convert voxelastic-simulate
                 voxelastic-verify voxelastic-verify-merge voxelastic-bench voxelastic-palpate-map voxelastic-plot)
      list(GET _vx_man_${page} 0 _help)
      list(GET _vx_man_${page} 1 _name)
      set(_program voxelastic)
      if(page STREQUAL "voxelastic-probe")
        set(_program voxelastic-probe)
      endif()
      add_custom_command(
        OUTPUT ${_vx_man_dir}/${page}.1
        COMMAND ${CMAKE_COMMAND} -E make_directory ${_vx_man_dir}
        COMMAND ${VOXELASTIC_HELP2MAN} --no-info --no-discard-stderr "--help-option=${_help}"
                "--version-string=${page} ${PROJECT_VERSION}" "--name=${_name}" "--output=${_vx_man_dir}/${page}.1"
                $<TARGET_FILE:${_program}>
        DEPENDS ${_program}
        COMMENT "help2man: ${page}.1"
        VERBATIM)
      list(APPEND _vx_pages ${_vx_man_dir}/${page}.1)
    endforeach()
    add_custom_target(voxelastic_man ALL DEPENDS ${_vx_pages})
    install(FILES ${_vx_pages} DESTINATION ${CMAKE_INSTALL_MANDIR}/man1)
  else()
    message(STATUS "voxelastic: help2man not found (apt-get install help2man): no man pages are installed")
  endif()
endif()
