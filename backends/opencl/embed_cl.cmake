# Turns one OpenCL C source into a C header holding it as a NUL-terminated
# char array, so that the library carries its kernels and never looks for
# files at run time. Bytes are written as hex so that no quoting or
# escaping of the source can go wrong.
#
# Usage: cmake -DIN=<file.cl> -DOUT=<header.h> -DNAME=<symbol>
#              -P embed_cl.cmake
file(READ "${IN}" hex HEX)
string(REGEX REPLACE "([0-9a-f][0-9a-f])" "0x\\1," bytes "${hex}")
# Twelve bytes per line keeps the generated file readable in a diff.
string(REGEX REPLACE "((0x[0-9a-f][0-9a-f],){12})" "\\1\n  " bytes
       "${bytes}")
get_filename_component(src_name "${IN}" NAME)
file(WRITE "${OUT}"
  "/* Generated from ${src_name} by embed_cl.cmake; do not edit. */\n"
  "static const char ${NAME}[] = {\n  ${bytes}0x00\n};\n")
