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
# GCC 12 at -O3 warns of overlapping memcpy inside std::string's own code
# (GCC bug 105329, a false positive fixed in GCC 13): kept as a warning.
if(CMAKE_CXX_COMPILER_ID STREQUAL "GNU" AND CMAKE_CXX_COMPILER_VERSION VERSION_LESS 13)
  target_compile_options(turncal_build_flags INTERFACE -Wno-error=restrict)
endif()
# clang's <math.h> makes NAN a float (__builtin_nanf): every `double x =
# NAN` would warn of a promotion. The GCC builds keep the check.
if(CMAKE_CXX_COMPILER_ID STREQUAL "Clang")
  target_compile_options(turncal_build_flags INTERFACE -Wno-double-promotion)
endif()
