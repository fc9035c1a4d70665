# Installs the library alone into a scratch prefix, checks that nothing
# installed needs cJSON, then builds a tiny consumer against it twice:
# through find_package(raypace) and through pkg-config; then compiles
# each installed header on its own.
file(REMOVE_RECURSE ${BIN})
file(MAKE_DIRECTORY ${BIN})
set(prefix ${BIN}/prefix)

function(run)
  execute_process(COMMAND ${ARGN} RESULT_VARIABLE rc OUTPUT_VARIABLE out
    ERROR_VARIABLE out)
  if(NOT rc EQUAL 0)
    message(FATAL_ERROR "failed (${rc}): ${ARGN}\n${out}")
  endif()
endfunction()

run(${CMAKE_COMMAND} -S ${SRC} -B ${BIN}/lib -G ${GENERATOR}
  -DCMAKE_C_COMPILER=${CC} -DCMAKE_BUILD_TYPE=Release
  -DRP_BUILD_TESTS=OFF -DRP_BUILD_SAMPLES=OFF -DRP_BUILD_CLI=OFF
  -DRP_BUILD_BENCH=OFF
  -DCMAKE_INSTALL_PREFIX=${prefix})
run(${CMAKE_COMMAND} --build ${BIN}/lib -j2)
run(${CMAKE_COMMAND} --install ${BIN}/lib)

# 0. The library stands without cJSON (sequences are the raypace
# command's): no installed file names it, neither as a dependency in the
# package files nor as a needed library or symbol in the binaries, whose
# dynamic string tables and archive symbol tables file(STRINGS) reads.
file(GLOB_RECURSE files ${prefix}/*)
foreach(f ${files})
  file(STRINGS ${f} hits REGEX "[cC][jJ][sS][oO][nN]")
  if(hits)
    list(GET hits 0 hit)
    message(FATAL_ERROR "${f} still names cJSON: ${hit}")
  endif()
endforeach()

# 1. CMake package, static and shared targets.
run(${CMAKE_COMMAND} -S ${SRC}/tests/install/consumer -B ${BIN}/consumer
  -G ${GENERATOR} -DCMAKE_C_COMPILER=${CC} -DCMAKE_PREFIX_PATH=${prefix})
run(${CMAKE_COMMAND} --build ${BIN}/consumer)
run(${BIN}/consumer/consumer_shared)
run(${BIN}/consumer/consumer_static)

# 2. pkg-config, as a Makefile-only app would use it.
find_program(PKG_CONFIG pkg-config REQUIRED)
file(GLOB pcdir ${prefix}/lib*/pkgconfig ${prefix}/lib/*/pkgconfig)
set(ENV{PKG_CONFIG_PATH} "${pcdir}")
execute_process(COMMAND ${PKG_CONFIG} --cflags --libs raypace
  OUTPUT_VARIABLE flags RESULT_VARIABLE rc OUTPUT_STRIP_TRAILING_WHITESPACE)
if(NOT rc EQUAL 0)
  message(FATAL_ERROR "pkg-config cannot find raypace in ${pcdir}")
endif()
separate_arguments(flags UNIX_COMMAND "${flags}")
run(${CC} ${SRC}/tests/install/consumer/consumer.c ${flags}
  -Wl,-rpath,${prefix}/lib -o ${BIN}/consumer_pc)
file(GLOB libdirs ${prefix}/lib ${prefix}/lib64 ${prefix}/lib/*-linux-gnu)
string(REPLACE ";" ":" ldpath "${libdirs}")
set(ENV{LD_LIBRARY_PATH} "${ldpath}")
run(${BIN}/consumer_pc)

# 3. Every installed header compiles on its own, with only pkg-config's
# flags: none leans on another being included first. Strict C11 as the
# project builds, with POSIX named (libuv's uv.h needs pthread types).
execute_process(COMMAND ${PKG_CONFIG} --cflags raypace
  OUTPUT_VARIABLE cflags OUTPUT_STRIP_TRAILING_WHITESPACE)
separate_arguments(cflags UNIX_COMMAND "${cflags}")
file(GLOB installed ${prefix}/include/raypace*.h)
foreach(h ${installed})
  get_filename_component(name ${h} NAME)
  file(WRITE ${BIN}/alone_${name}.c "#include <${name}>\nint rp_alone;\n")
  run(${CC} -std=c11 -D_POSIX_C_SOURCE=200809L -Wall -Wextra -Werror
    -Wstrict-prototypes -fsyntax-only ${cflags} ${BIN}/alone_${name}.c)
endforeach()
message(STATUS "consumer built and ran through find_package and "
  "pkg-config; every installed header compiles alone")
