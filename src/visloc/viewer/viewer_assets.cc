#include "visloc/viewer/viewer_assets.h"

// Each asset is assembled into .rodata with .incbin (GNU as and clang's
// integrated assembler, x86-64 and aarch64), between a begin and an end
// symbol; CMake passes the paths and makes this file depend on them.
#define VISLOC_STRINGIFY_(x) #x
#define VISLOC_STRINGIFY(x) VISLOC_STRINGIFY_(x)
#define VISLOC_INCBIN(symbol, path)                                                                   \
  __asm__(".pushsection .rodata\n.balign 16\n.globl " #symbol "_begin\n" #symbol "_begin:\n.incbin \"" path \
          "\"\n.globl " #symbol "_end\n" #symbol "_end:\n.byte 0\n.popsection\n");                      \
  extern "C" const char symbol##_begin[];                                                            \
  extern "C" const char symbol##_end[];

VISLOC_INCBIN(visloc_viewer_page, VISLOC_VIEWER_PAGE_PATH)
VISLOC_INCBIN(visloc_viewer_app, VISLOC_VIEWER_APP_PATH)
#if VISLOC_HAVE_THREE_JS
VISLOC_INCBIN(visloc_three_core, VISLOC_THREE_CORE_PATH)
VISLOC_INCBIN(visloc_three_module, VISLOC_THREE_MODULE_PATH)
#endif

namespace visloc::viewer_assets {

namespace {
std::string_view view(const char* begin, const char* end) {
  return std::string_view(begin, static_cast<size_t>(end - begin));
}
}  // namespace

bool available() { return VISLOC_HAVE_THREE_JS != 0; }
std::string_view page_template() { return view(visloc_viewer_page_begin, visloc_viewer_page_end); }
std::string_view app_script() { return view(visloc_viewer_app_begin, visloc_viewer_app_end); }
#if VISLOC_HAVE_THREE_JS
std::string_view three_core() { return view(visloc_three_core_begin, visloc_three_core_end); }
std::string_view three_module() { return view(visloc_three_module_begin, visloc_three_module_end); }
#else
std::string_view three_core() { return {}; }
std::string_view three_module() { return {}; }
#endif
const char* three_version() { return VISLOC_THREE_VERSION; }

}  // namespace visloc::viewer_assets
