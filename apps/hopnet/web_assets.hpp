// apps/hopnet/web_assets.hpp
// What the hopnet program's HTML pages (the evaluation report, the training curves, the rollout
// viewer) are made of: their templates (apps/hopnet/web/, compiled in by
// cmake/embed_text.cmake) and the JavaScript libraries they inline, three.js and Chart.js from
// npm (installed by scripts/setup.sh). Every page is one self-contained file that opens offline:
// Chart.js goes in as a classic script; three.js, which npm ships only as ES modules, goes in as
// an import map whose entries are data: URLs. std + nlohmann-json.
#pragma once

#include "hopnet_web_templates.hpp"
#include "topos/data/json.hpp"

#include <nlohmann/json.hpp>

#include <cstdlib>
#include <filesystem>
#include <map>
#include <stdexcept>
#include <string>
#include <string_view>
#include <utility>

#ifndef TOPOS_JS_DIR
#define TOPOS_JS_DIR "/usr/local/share/topos/js"
#endif

namespace hopnet_web {

/// The folder whose node_modules holds three and chart.js: $TOPOS_JS_DIR, else the build's.
inline std::filesystem::path js_dir() {
  const char* env = std::getenv("TOPOS_JS_DIR");
  return (env && *env) ? std::filesystem::path(env) : std::filesystem::path(TOPOS_JS_DIR);
}

/// One file of an npm package under js_dir(); a missing one is an error that says how to get it.
inline std::string read_js_file(const std::string& package, const std::string& file) {
  const auto path = js_dir() / "node_modules" / package / file;
  if (!std::filesystem::is_regular_file(path))
    throw std::runtime_error(
        "the HTML report needs the JavaScript library '" + package + "', and " + path.string() +
        " does not exist: run scripts/setup.sh (it installs it " +
        "with npm), or set TOPOS_JS_DIR to the folder whose node_modules holds " +
        "three and chart.js (or pass --no-report)");
  return topos::data::read_text_file(path);
}

/// Fails now, with read_js_file's message, when a library the pages inline is missing, so that
/// a long run does not find out at its end.
inline void require_js_libraries() {
  for (const auto& [package, file] :
       {std::pair<std::string, std::string>{"three", "build/three.module.js"},
        {"three", "build/three.core.js"},
        {"three", "examples/jsm/controls/OrbitControls.js"},
        {"chart.js", "dist/chart.umd.js"}})
    if (!std::filesystem::is_regular_file(js_dir() / "node_modules" / package / file))
      read_js_file(package, file);
}

inline std::string base64(std::string_view in) {
  static const char* abc = "ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
  std::string out;
  out.reserve((in.size() + 2) / 3 * 4);
  std::size_t i = 0;
  for (; i + 2 < in.size(); i += 3) {
    const auto n = (std::uint32_t(std::uint8_t(in[i])) << 16) |
                   (std::uint32_t(std::uint8_t(in[i + 1])) << 8) | std::uint8_t(in[i + 2]);
    for (int s : {18, 12, 6, 0}) out += abc[(n >> s) & 63];
  }
  if (i < in.size()) {
    const std::uint32_t n = (std::uint32_t(std::uint8_t(in[i])) << 16) |
                            (i + 1 < in.size() ? std::uint32_t(std::uint8_t(in[i + 1])) << 8 : 0);
    out += abc[(n >> 18) & 63];
    out += abc[(n >> 12) & 63];
    out += i + 1 < in.size() ? abc[(n >> 6) & 63] : '=';
    out += '=';
  }
  return out;
}

/// Text that can stand inside <script>...</script>: the HTML parser ends a script at "</script"
/// and changes state at "<!--", whatever the JavaScript around them; "<\/" and "<\!--" mean
/// the same inside JavaScript strings, regular expressions and comments, where they occur.
inline std::string script_safe(std::string s) {
  for (std::size_t p = 0; (p = s.find("</", p)) != std::string::npos; p += 3)
    s.replace(p, 2, "<\\/");
  for (std::size_t p = 0; (p = s.find("<!--", p)) != std::string::npos; p += 5)
    s.replace(p, 4, "<\\!--");
  return s;
}

/// JSON for a <script type="application/json"> block ('<' escaped, so no tag can end it).
inline std::string script_json(const nlohmann::json& j) {
  std::string s = j.dump();
  std::string out;
  out.reserve(s.size());
  for (char c : s) {
    if (c == '<')
      out += "\\u003c";
    else
      out += c;
  }
  return out;
}

/// Chart.js (UMD build) as an inline classic script: defines the global `Chart`.
inline std::string chart_js_script() {
  return "<script>" + script_safe(read_js_file("chart.js", "dist/chart.umd.js")) + "</script>";
}

/// three.js as an import map: `import * as THREE from "three"` and
/// `import {OrbitControls} from "three/addons/controls/OrbitControls.js"` work in the page's
/// module scripts without a server. three.module.js imports "./three.core.js", which a data: URL
/// cannot resolve, so that import is renamed to the mapped specifier "three/core".
inline std::string three_import_map() {
  const std::string core = read_js_file("three", "build/three.core.js");
  std::string module = read_js_file("three", "build/three.module.js");
  const std::string from = "from './three.core.js'";
  std::size_t count = 0;
  for (std::size_t p = 0; (p = module.find(from, p)) != std::string::npos; ++count) {
    module.replace(p, from.size(), "from 'three/core'");
  }
  if (count == 0)
    throw std::runtime_error(
        (js_dir() / "node_modules/three/build/three.module.js").string() +
        ": does not import './three.core.js' as three 0.187 does; install the " +
        "version scripts/setup.sh pins");
  const std::string controls = read_js_file("three", "examples/jsm/controls/OrbitControls.js");
  const auto url = [](const std::string& js) {
    return "data:text/javascript;base64," + base64(js);
  };
  const nlohmann::json map{{"imports",
                            {{"three/core", url(core)},
                             {"three", url(module)},
                             {"three/addons/controls/OrbitControls.js", url(controls)}}}};
  return "<script type=\"importmap\">" + script_json(map) + "</script>";
}

/// `tmpl` with every "@@NAME@@" replaced by slots[NAME]. A name without a slot, or a slot the
/// template does not use, is a programming error (the templates and their writers go together).
inline std::string fill_template(std::string_view tmpl,
                                 const std::map<std::string, std::string>& slots,
                                 const std::string& what) {
  std::string out;
  std::map<std::string, int> used;
  std::size_t p = 0;
  while (true) {
    const auto a = tmpl.find("@@", p);
    if (a == std::string_view::npos) break;
    const auto b = tmpl.find("@@", a + 2);
    if (b == std::string_view::npos)
      throw std::logic_error(what + " template: unclosed @@ at " + std::to_string(a));
    const std::string name(tmpl.substr(a + 2, b - a - 2));
    const auto it = slots.find(name);
    if (it == slots.end())
      throw std::logic_error(what + " template: no value for @@" + name + "@@");
    out.append(tmpl.substr(p, a - p));
    out += it->second;
    ++used[name];
    p = b + 2;
  }
  out.append(tmpl.substr(p));
  for (const auto& [name, value] : slots)
    if (!used.count(name))
      throw std::logic_error(what + " template: does not use @@" + name + "@@");
  return out;
}

}  // namespace hopnet_web
