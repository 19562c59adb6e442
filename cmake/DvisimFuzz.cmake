# DVISIM_FUZZ: a build for fuzzing (tests/fuzz/, docs/HARDENING.md). Needs clang with libFuzzer (Debian:
# clang, libclang-rt-14-dev, libomp-dev). Everything in this tree is compiled with coverage instrumentation for
# libFuzzer and with AddressSanitizer and UndefinedBehaviorSanitizer (any UB aborts); the fuzz targets link
# libFuzzer's main. Use a separate build directory (build-fuzz), not the normal one.
option(DVISIM_FUZZ "Build the libFuzzer targets (tests/fuzz/) with ASan+UBSan; needs clang" OFF)
if(DVISIM_FUZZ)
  if(NOT CMAKE_CXX_COMPILER_ID STREQUAL "Clang")
    message(FATAL_ERROR "DVISIM_FUZZ needs clang (libFuzzer): configure with -DCMAKE_CXX_COMPILER=clang++")
  endif()
  set(DVISIM_SANITIZE -fsanitize=address,undefined -fno-sanitize-recover=undefined -fno-omit-frame-pointer)
  add_compile_options(-fsanitize=fuzzer-no-link ${DVISIM_SANITIZE} -g)
  add_link_options(${DVISIM_SANITIZE})
  message(STATUS "dvisim: fuzzing build (libFuzzer, ASan, UBSan)")
endif()
