# Cross-compiling for aarch64 Linux with Debian's crossbuild-essential-arm64 into a
# sysroot of Debian arm64 packages (scripts/device-build.sh makes both). Tests run
# under qemu-aarch64 through CMAKE_CROSSCOMPILING_EMULATOR, so ctest works as usual.
#   cmake -DCMAKE_TOOLCHAIN_FILE=cmake/aarch64-linux-gnu.cmake -DVISLOC_SYSROOT=DIR ...
set(CMAKE_SYSTEM_NAME Linux)
set(CMAKE_SYSTEM_PROCESSOR aarch64)
set(VISLOC_SYSROOT "$ENV{VISLOC_SYSROOT}" CACHE PATH "arm64 sysroot (scripts/device-build.sh)")
list(APPEND CMAKE_TRY_COMPILE_PLATFORM_VARIABLES VISLOC_SYSROOT)  # try_compile projects see it too
if(NOT VISLOC_SYSROOT OR NOT EXISTS "${VISLOC_SYSROOT}/usr/include")
  message(FATAL_ERROR "aarch64 toolchain: VISLOC_SYSROOT='${VISLOC_SYSROOT}' is not a sysroot "
                      "(scripts/device-build.sh --stage sysroot makes one)")
endif()
set(CMAKE_SYSROOT "${VISLOC_SYSROOT}")
set(CMAKE_C_COMPILER aarch64-linux-gnu-gcc)
set(CMAKE_CXX_COMPILER aarch64-linux-gnu-g++)
set(CMAKE_LIBRARY_ARCHITECTURE aarch64-linux-gnu)
set(CMAKE_FIND_ROOT_PATH "${VISLOC_SYSROOT}")
set(CMAKE_FIND_ROOT_PATH_MODE_PROGRAM NEVER)
set(CMAKE_FIND_ROOT_PATH_MODE_LIBRARY ONLY)
set(CMAKE_FIND_ROOT_PATH_MODE_INCLUDE ONLY)
set(CMAKE_FIND_ROOT_PATH_MODE_PACKAGE ONLY)
# The sysroot's shared libraries find each other (rpath-link) at link time.
set(_libdirs "${VISLOC_SYSROOT}/lib/aarch64-linux-gnu;${VISLOC_SYSROOT}/usr/lib/aarch64-linux-gnu")
foreach(d IN LISTS _libdirs)
  string(APPEND CMAKE_EXE_LINKER_FLAGS_INIT " -Wl,-rpath-link,${d}")
  string(APPEND CMAKE_SHARED_LINKER_FLAGS_INIT " -Wl,-rpath-link,${d}")
endforeach()
set(CMAKE_CROSSCOMPILING_EMULATOR qemu-aarch64;-L;${VISLOC_SYSROOT})
