# cmake -DIN=raw.h -DOUT=name.spv.h -P DeepcanvasEmbedSpirv.cmake
# glslangValidator --vn emits `const uint32_t NAME[] = {...};` without including <stdint.h>;
# this makes the generated header self-contained.
file(READ ${IN} body)
file(WRITE ${OUT}.tmp "// Generated from SPIR-V by glslangValidator; do not edit.\n#pragma once\n#include <stdint.h>\n${body}")
file(RENAME ${OUT}.tmp ${OUT})
