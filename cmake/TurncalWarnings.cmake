# Warnings (as errors by default) and sanitizers, applied to every target
# of the project through one interface library.
add_library(turncal_build_flags INTERFACE)
target_compile_options(turncal_build_flags INTERFACE
  -Wall -Wextra -Wpedantic -Wshadow -Wconversion -Wsign-conversion
  -Wnon-virtual-dtor -Wold-style-cast -Wcast-align -Woverloaded-virtual
  -Wnull-dereference -Wdouble-promotion -Wformat=2 -Wimplicit-fallthrough)
if(TURNCAL_WERROR)
  target_compile_options(turncal_build_flags INTERFACE -Werror)
endif()
if(TURNCAL_SANITIZE)
  target_compile_options(turncal_build_flags INTERFACE
    -fsanitize=address,undefined -fno-sanitize-recover=all -fno-omit-frame-pointer)
  target_link_options(turncal_build_flags INTERFACE -fsanitize=address,undefined)
endif()
