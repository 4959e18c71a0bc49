# Compiles every shaders/*.comp to SPIR-V with glslang at build time and embeds the words in a
# generated header (one uint32_t array per shader), so binaries never look for .spv files on disk.
find_program(GLSLANG_VALIDATOR NAMES glslangValidator glslang REQUIRED)
set(DEEPCANVAS_EMBED_SPIRV_SCRIPT ${CMAKE_CURRENT_LIST_DIR}/DeepcanvasEmbedSpirv.cmake)

# deepcanvas_compile_shaders(TARGET DIR): every DIR/*.comp; #include resolves against the
# project's shaders/include (the shared GLSL/C++ headers) and DIR/include, so test-only shaders
# elsewhere (tests/client_gpu/shaders) use the same shared headers.
function(deepcanvas_compile_shaders target shader_dir)
  file(GLOB shader_sources CONFIGURE_DEPENDS ${shader_dir}/*.comp)
  file(GLOB shader_includes CONFIGURE_DEPENDS ${shader_dir}/include/*.h
       ${PROJECT_SOURCE_DIR}/shaders/include/*.h)
  set(out_dir ${CMAKE_CURRENT_BINARY_DIR}/generated/deepcanvas/shaders)
  set(headers)
  foreach(src ${shader_sources})
    get_filename_component(name ${src} NAME_WE)
    set(out ${out_dir}/${name}.spv.h)
    add_custom_command(
      OUTPUT ${out}
      COMMAND ${CMAKE_COMMAND} -E make_directory ${out_dir}
      COMMAND ${GLSLANG_VALIDATOR} -V --target-env vulkan1.1 -I${shader_dir}/include
              -I${PROJECT_SOURCE_DIR}/shaders/include
              --vn deepcanvas_spv_${name} -o ${out_dir}/${name}.spv.raw.h ${src}
      COMMAND ${CMAKE_COMMAND} -DIN=${out_dir}/${name}.spv.raw.h -DOUT=${out}
              -P ${DEEPCANVAS_EMBED_SPIRV_SCRIPT}
      DEPENDS ${src} ${shader_includes} ${DEEPCANVAS_EMBED_SPIRV_SCRIPT}
      COMMENT "glslang: ${name}.comp -> SPIR-V"
      VERBATIM)
    list(APPEND headers ${out})
  endforeach()
  add_custom_target(${target}_compile DEPENDS ${headers})
  add_library(${target} INTERFACE)
  add_dependencies(${target} ${target}_compile)
  target_include_directories(${target} INTERFACE ${CMAKE_CURRENT_BINARY_DIR}/generated)
endfunction()
