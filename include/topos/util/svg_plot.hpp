// topos/util/svg_plot.hpp
// A small SVG line chart (series against their index: frames, epochs) for the programs' reports,
// viewable in any browser without a plotting dependency. std only.
#pragma once

#include <algorithm>
#include <cmath>
#include <sstream>
#include <string>
#include <utility>
#include <vector>

namespace topos {

struct SvgPlotOptions {
  std::string xlabel = "step", ylabel;
  double ymin = 0;
  double ymax = NAN;  ///< NaN: the largest finite value
  double x0 = 0;      ///< the x value of index 0 (e.g. 1 for epochs counted from 1)
};

/// One polyline per named series, legend in the top-left corner; non-finite values are skipped.
inline std::string svg_line_plot(
    const std::vector<std::pair<std::string, std::vector<double>>>& series,
    const SvgPlotOptions& opt = {}) {
  const double W = 640, H = 360, L = 60, B = 40;
  double ymax = opt.ymax;
  std::size_t n = 0;
  if (!std::isfinite(ymax)) {
    ymax = opt.ymin + 1e-12;
    for (const auto& [name, v] : series)
      for (double y : v)
        if (std::isfinite(y)) ymax = std::max(ymax, y);
  }
  for (const auto& [name, v] : series) n = std::max(n, v.size());
  const double span = std::max(ymax - opt.ymin, 1e-12);
  std::ostringstream o;
  o << "<svg xmlns='http://www.w3.org/2000/svg' width='" << W << "' height='" << H
    << "' font-family='sans-serif' font-size='12'>\n";
  o << "<rect width='100%' height='100%' fill='white'/>\n<line x1='" << L << "' y1='" << H - B
    << "' x2='" << W - 10 << "' y2='" << H - B << "' stroke='black'/>\n";
  o << "<line x1='" << L << "' y1='10' x2='" << L << "' y2='" << H - B << "' stroke='black'/>\n";
  o << "<text x='" << W / 2 << "' y='" << H - 8 << "' text-anchor='middle'>" << opt.xlabel
    << "</text>\n<text x='12' y='" << H / 2 << "' transform='rotate(-90 12 " << H / 2
    << ")' text-anchor='middle'>" << opt.ylabel << "</text>\n";
  o << "<text x='" << L - 4 << "' y='14' text-anchor='end'>" << ymax << "</text><text x='" << L - 4
    << "' y='" << H - B << "' text-anchor='end'>" << opt.ymin << "</text><text x='" << L << "' y='"
    << H - B + 14 << "' text-anchor='middle'>" << opt.x0 << "</text><text x='" << W - 10 << "' y='"
    << H - B + 14 << "' text-anchor='end'>" << opt.x0 + static_cast<double>(n > 0 ? n - 1 : 0)
    << "</text>\n";
  const char* colors[] = {"#1f77b4", "#d62728", "#2ca02c", "#9467bd", "#ff7f0e", "#8c564b"};
  int k = 0;
  for (const auto& [name, v] : series) {
    o << "<polyline fill='none' stroke='" << colors[k % 6] << "' stroke-width='2' points='";
    for (std::size_t i = 0; i < v.size(); ++i)
      if (std::isfinite(v[i]))
        o << L + (W - 10 - L) * static_cast<double>(i) /
                     static_cast<double>(std::max<std::size_t>(n - 1, 1))
          << "," << (H - B) - (H - B - 10) * (std::clamp(v[i], opt.ymin, ymax) - opt.ymin) / span
          << " ";
    o << "'/>\n<text x='" << L + 10 << "' y='" << 24 + 16 * k << "' fill='" << colors[k % 6] << "'>"
      << name << "</text>\n";
    ++k;
  }
  o << "</svg>\n";
  return o.str();
}

}  // namespace topos
