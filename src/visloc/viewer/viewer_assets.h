#pragma once
// The files the viewer's page is made of, built into the library (no file is
// read at run time): the page template and its code (this folder), and
// three.js from npm (package.json, package-lock.json; `npm ci` here, which
// scripts/setup.sh runs). Without three.js at build time the page cannot be
// written and `available()` is false.
#include <string_view>

namespace visloc::viewer_assets {

bool available();
std::string_view page_template();  // viewer_page.html
std::string_view app_script();     // viewer_app.js
std::string_view three_core();     // three/build/three.core.js
std::string_view three_module();   // three/build/three.module.js
const char* three_version();       // from package.json at build time

}  // namespace visloc::viewer_assets
