# Compiles every shaders/*.comp to SPIR-V with glslang at build time and embeds the words in a
# generated header (one uint32_t array per shader), so binaries never look for .spv files on disk.
find_program(GLSLANG_VALIDATOR NAMES glslangValidator glslang REQUIRED)

function(deepcanvas_compile_shaders target shader_dir)
  file(GLOB shader_sources CONFIGURE_DEPENDS ${shader_dir}/*.comp)
  file(GLOB shader_includes CONFIGURE_DEPENDS ${shader_dir}/include/*.h)
  set(out_dir ${CMAKE_CURRENT_BINARY_DIR}/generated/deepcanvas/shaders)
  set(headers)
  foreach(src ${shader_sources})
    get_filename_component(name ${src} NAME_WE)
    set(out ${out_dir}/${name}.spv.h)
    add_custom_command(
      OUTPUT ${out}
      COMMAND ${CMAKE_COMMAND} -E make_directory ${out_dir}
      COMMAND ${GLSLANG_VALIDATOR} -V --target-env vulkan1.1 -I${shader_dir}/include
              --vn deepcanvas_spv_${name} -o ${out} ${src}
      DEPENDS ${src} ${shader_includes}
      COMMENT "glslang: ${name}.comp -> SPIR-V"
      VERBATIM)
    list(APPEND headers ${out})
  endforeach()
  add_custom_target(${target}_compile DEPENDS ${headers})
  add_library(${target} INTERFACE)
  add_dependencies(${target} ${target}_compile)
  target_include_directories(${target} INTERFACE ${CMAKE_CURRENT_BINARY_DIR}/generated)
endfunction()
