// A small line/point plot written twice: an SVG document and a PNG raster
// (OpenCV), for the reports of `visloc eval` and the benchmarks.
#pragma once

#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include <algorithm>
#include <filesystem>
#include <iomanip>
#include <sstream>
#include <string>
#include <string_view>
#include <vector>

#include "visloc/util/file_io.h"

namespace visloc {

// One plot in two encodings: an SVG document and a PNG raster (OpenCV).
struct Plot {
  int w = 640, h = 440, left = 60, right = 20, top = 30, bottom = 50;
  double x0 = 0, x1 = 1, y0 = 0, y1 = 1;
  std::ostringstream svg;
  cv::Mat png;
  Plot(const std::string& title, const std::string& xlabel, const std::string& ylabel, double xa, double xb, double ya,
       double yb)
      : x0(xa), x1(xb), y0(ya), y1(yb), png(h, w, CV_8UC3, cv::Scalar(255, 255, 255)) {
    svg << "<svg xmlns='http://www.w3.org/2000/svg' width='" << w << "' height='" << h << "' font-family='sans-serif' "
        << "font-size='12'>\n<rect width='100%' height='100%' fill='white'/>\n"
        << "<text x='" << w / 2 << "' y='18' text-anchor='middle' font-size='14'>" << xml(title) << "</text>\n"
        << "<text x='" << w / 2 << "' y='" << h - 10 << "' text-anchor='middle'>" << xml(xlabel) << "</text>\n"
        << "<text x='14' y='" << h / 2 << "' transform='rotate(-90 14 " << h / 2 << ")' text-anchor='middle'>"
        << xml(ylabel) << "</text>\n";
    int baseline = 0;
    const int title_width = cv::getTextSize(title, cv::FONT_HERSHEY_SIMPLEX, 0.5, 1, &baseline).width;
    cv::putText(png, title, {std::max(left + 60, (w - title_width) / 2), 18}, cv::FONT_HERSHEY_SIMPLEX, 0.5,
                {0, 0, 0}, 1, cv::LINE_AA);
    cv::putText(png, xlabel, {w / 2 - 60, h - 10}, cv::FONT_HERSHEY_SIMPLEX, 0.45, {0, 0, 0}, 1, cv::LINE_AA);
    cv::putText(png, ylabel, {4, top - 8}, cv::FONT_HERSHEY_SIMPLEX, 0.4, {0, 0, 0}, 1, cv::LINE_AA);
    // Axes box and ticks.
    line(x0, y0, x1, y0, "#000", {0, 0, 0});
    line(x0, y0, x0, y1, "#000", {0, 0, 0});
    for (int i = 0; i <= 4; ++i) {
      const double xv = x0 + (x1 - x0) * i / 4, yv = y0 + (y1 - y0) * i / 4;
      label(xv, y0, fmt(xv), 0, 16);
      label(x0, yv, fmt(yv), -30, 4);
    }
  }
  // Text for SVG: &, < and > escaped (titles and labels may hold paths).
  static std::string xml(const std::string& text) {
    std::string out;
    for (char c : text) {
      if (c == '&') out += "&amp;";
      else if (c == '<') out += "&lt;";
      else if (c == '>') out += "&gt;";
      else out += c;
    }
    return out;
  }
  static std::string fmt(double v) {
    std::ostringstream s;
    s << std::setprecision(3) << v;
    return s.str();
  }
  double px(double x) const { return left + (x - x0) / (x1 - x0) * (w - left - right); }
  double py(double y) const { return h - bottom - (y - y0) / (y1 - y0) * (h - top - bottom); }
  void line(double xa, double ya, double xb, double yb, const char* color, cv::Scalar bgr, int width = 1) {
    svg << "<line x1='" << px(xa) << "' y1='" << py(ya) << "' x2='" << px(xb) << "' y2='" << py(yb) << "' stroke='"
        << color << "' stroke-width='" << width << "'/>\n";
    cv::line(png, {int(px(xa)), int(py(ya))}, {int(px(xb)), int(py(yb))}, bgr, width, cv::LINE_AA);
  }
  void point(double x, double y, const char* color, cv::Scalar bgr, int r = 3) {
    svg << "<circle cx='" << px(x) << "' cy='" << py(y) << "' r='" << r << "' fill='" << color << "'/>\n";
    cv::circle(png, {int(px(x)), int(py(y))}, r, bgr, cv::FILLED, cv::LINE_AA);
  }
  void label(double x, double y, const std::string& text, int dx, int dy) {
    svg << "<text x='" << px(x) + dx << "' y='" << py(y) + dy << "'>" << xml(text) << "</text>\n";
    cv::putText(png, text, {int(px(x)) + dx, int(py(y)) + dy}, cv::FONT_HERSHEY_SIMPLEX, 0.4, {0, 0, 0}, 1,
                cv::LINE_AA);
  }
  // A cumulative curve: a step up by 1 / count at each of the sorted values,
  // drawn to xmax (values beyond it at xmax).
  void cumulative_steps(const std::vector<double>& sorted, double count, double xmax) {
    double prev_x = 0, prev_y = 0;
    for (size_t i = 0; i < sorted.size(); ++i) {
      const double x = std::min(sorted[i], xmax), y = double(i + 1) / count;
      line(prev_x, prev_y, x, prev_y, "#1f77b4", {180, 119, 31}, 2);
      line(x, prev_y, x, y, "#1f77b4", {180, 119, 31}, 2);
      prev_x = x;
      prev_y = y;
    }
    line(prev_x, prev_y, xmax, prev_y, "#1f77b4", {180, 119, 31}, 2);
  }
  void save(const std::filesystem::path& stem) {
    svg << "</svg>\n";
    write_file_atomic(stem.string() + ".svg", svg.str());
    std::vector<uchar> buf;
    cv::imencode(".png", png, buf);
    write_file_atomic(stem.string() + ".png", std::string_view(reinterpret_cast<const char*>(buf.data()), buf.size()));
  }
};

}  // namespace visloc
