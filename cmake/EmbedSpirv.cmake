# cmake -DSPV=in.spv -DOUT=out.cpp -DNAME=name -P EmbedSpirv.cmake
file(READ ${SPV} _hex HEX)
string(LENGTH "${_hex}" _len)
math(EXPR _words "${_len} / 8")
# SPIR-V words are little-endian on disk: reverse the 4 bytes of each word.
string(REGEX REPLACE "(..)(..)(..)(..)" "0x\\4\\3\\2\\1u," _body "${_hex}")
string(REGEX REPLACE "((0x........u,){8})" "\\1\n" _body "${_body}")
file(WRITE ${OUT} "// Generated from ${NAME}.comp\n#include <cstddef>\n#include <cstdint>\nnamespace vkunroll::embedded {\nextern const uint32_t spv_${NAME}[] = {\n${_body}\n};\nextern const size_t spv_${NAME}_words = ${_words};\n}\n")
