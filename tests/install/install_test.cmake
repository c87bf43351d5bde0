# ctest -L install: `cmake --install` into a temporary prefix, then what a user does with it:
# run the programs from there, complete a command line, read a man page, and build and run
# examples/find_package against the installed tree with find_package(voxelastic).
# Run by tests/CMakeLists.txt with -DBUILD_DIR, -DSOURCE_DIR, -DWORK_DIR, -DHAVE_HELP2MAN,
# -DCXX_COMPILER, -DVERSION.
cmake_minimum_required(VERSION 3.20)

function(run_checked what)
  execute_process(COMMAND ${ARGN} RESULT_VARIABLE code OUTPUT_VARIABLE out ERROR_VARIABLE err)
  if(NOT code EQUAL 0)
    message(FATAL_ERROR "${what} failed (exit ${code}):\n${out}\n${err}")
  endif()
  set(run_out "${out}" PARENT_SCOPE)
endfunction()

function(expect_contains text pattern what)
  string(FIND "${text}" "${pattern}" at)
  if(at EQUAL -1)
    message(FATAL_ERROR "${what}: expected '${pattern}' in:\n${text}")
  endif()
endfunction()

set(prefix ${WORK_DIR}/prefix)
file(REMOVE_RECURSE ${WORK_DIR})
file(MAKE_DIRECTORY ${WORK_DIR})

# install
run_checked("cmake --install" ${CMAKE_COMMAND} --install ${BUILD_DIR} --prefix ${prefix})

# the files a user and a library user find there
set(expected
  bin/voxelastic bin/voxelastic-probe
  share/bash-completion/completions/voxelastic share/bash-completion/completions/voxelastic-probe
  share/doc/voxelastic/LICENSE
  include/voxelastic/base/version.h include/voxelastic/sim/simulation.h include/voxelastic/io/volume_io.h
  include/voxelastic/convert/prepare.h
  lib/libvoxelastic_core.a lib/libvoxelastic_pipeline.a
  lib/cmake/voxelastic/voxelastic-config.cmake lib/cmake/voxelastic/voxelastic-config-version.cmake
  lib/cmake/voxelastic/voxelastic-targets.cmake)
if(HAVE_HELP2MAN)
  list(APPEND expected share/man/man1/voxelastic.1 share/man/man1/voxelastic-convert.1 share/man/man1/voxelastic-probe.1)
endif()
foreach(f ${expected})
  if(NOT EXISTS ${prefix}/${f})
    message(FATAL_ERROR "cmake --install did not install ${f}")
  endif()
endforeach()
# no VTK header leaks into what is installed (the pipeline's public headers are VTK-free)
file(GLOB_RECURSE headers ${prefix}/include/voxelastic/*.h)
foreach(h ${headers})
  file(STRINGS ${h} vtk_includes REGEX "#include <vtk")
  if(vtk_includes)
    message(FATAL_ERROR "${h} includes VTK: ${vtk_includes}")
  endif()
endforeach()

# the program runs from the prefix
run_checked("voxelastic --version" ${prefix}/bin/voxelastic --version)
expect_contains("${run_out}" "voxelastic ${VERSION}" "voxelastic --version")
run_checked("voxelastic phantom" ${prefix}/bin/voxelastic phantom sphere --size 16 -o ${WORK_DIR}/s.nrrd)
expect_contains("${run_out}" "phantom sphere: 16x16x16 voxels" "voxelastic phantom")

# the Slicer CLI module: its description, from the installed program
file(GLOB slicer_module ${prefix}/lib*/voxelastic/slicer-cli/voxelastic-convert)
if(NOT slicer_module)
  message(FATAL_ERROR "cmake --install did not install lib/voxelastic/slicer-cli/voxelastic-convert")
endif()
run_checked("voxelastic-convert --xml" ${slicer_module} --xml)
expect_contains("${run_out}" "<title>voxelastic convert</title>" "voxelastic-convert --xml")

# man pages: one per subcommand that voxelastic --help lists, and the subcommand's options in its page
if(HAVE_HELP2MAN)
  run_checked("voxelastic --help" ${prefix}/bin/voxelastic --help)
  string(FIND "${run_out}" "Subcommands:" at)
  string(SUBSTRING "${run_out}" ${at} -1 subcommands)
  string(REGEX MATCHALL "\n  [a-z][a-z-]*" subcommands "${subcommands}")
  list(LENGTH subcommands n)
  if(n LESS 8)
    message(FATAL_ERROR "voxelastic --help lists ${n} subcommands: ${subcommands}")
  endif()
  foreach(s ${subcommands})
    string(STRIP "${s}" s)
    if(NOT EXISTS ${prefix}/share/man/man1/voxelastic-${s}.1)
      message(FATAL_ERROR "no man page for voxelastic ${s} (share/man/man1/voxelastic-${s}.1): add it in cmake/install.cmake")
    endif()
  endforeach()
  file(READ ${prefix}/share/man/man1/voxelastic-convert.1 page)
  expect_contains("${page}" "threshold" "voxelastic-convert.1")
  expect_contains("${page}" ".TH VOXELASTIC-CONVERT" "voxelastic-convert.1")
endif()

# bash completion: subcommands, a subcommand's options, the probe's options
set(completion ${prefix}/share/bash-completion/completions/voxelastic)
foreach(case "voxelastic con|convert" "voxelastic -q conv|convert" "voxelastic convert in.nrrd --thr|--threshold"
             "voxelastic phantom --tis|--tissue-hu" "voxelastic-probe --head|--headless")
  string(REPLACE "|" ";" parts "${case}")
  list(GET parts 0 line)
  list(GET parts 1 want)
  separate_arguments(words UNIX_COMMAND "${line}")
  run_checked("completion of '${line}'" env PATH=${prefix}/bin:$ENV{PATH} bash ${SOURCE_DIR}/tests/install/complete.sh
              ${completion} ${words})
  string(STRIP "${run_out}" got)
  if(NOT got STREQUAL want)
    message(FATAL_ERROR "completion of '${line}': expected '${want}', got '${got}'")
  endif()
endforeach()

# a program of one's own against the installed tree (examples/find_package)
run_checked("configuring examples/find_package" ${CMAKE_COMMAND} -S ${SOURCE_DIR}/examples/find_package
            -B ${WORK_DIR}/example -DCMAKE_BUILD_TYPE=Release -DCMAKE_PREFIX_PATH=${prefix}
            -DCMAKE_CXX_COMPILER=${CXX_COMPILER})
# the package found is the installed one, not the build tree
file(STRINGS ${WORK_DIR}/example/CMakeCache.txt dir_line REGEX "^voxelastic_DIR:")
expect_contains("${dir_line}" "${prefix}/lib/cmake/voxelastic" "voxelastic_DIR")
run_checked("building examples/find_package" ${CMAKE_COMMAND} --build ${WORK_DIR}/example -j 2)
run_checked("running sphere_model" ${WORK_DIR}/example/sphere_model ${WORK_DIR})
expect_contains("${run_out}" "voxelastic ${VERSION}: sphere" "sphere_model")
message(STATUS "${run_out}")
file(REMOVE_RECURSE ${WORK_DIR})
