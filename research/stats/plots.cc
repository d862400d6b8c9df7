#include "research/stats/plots.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <functional>
#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <stdexcept>

namespace stackgen::stats {
namespace {

namespace fs = std::filesystem;

// matplotlib's first two colours (blue, orange), BGR
const cv::Scalar kSeriesColours[] = {cv::Scalar(180, 119, 31), cv::Scalar(14, 127, 255)};
const cv::Scalar kBlack(0, 0, 0);
const cv::Scalar kGrid(225, 225, 225);
const cv::Scalar kWhite(255, 255, 255);
constexpr int kFont = cv::FONT_HERSHEY_SIMPLEX;
constexpr double kTextScale = 0.45;
constexpr double kTitleScale = 0.6;
// histogram bins: 36 of 10 degrees over (-180, 180]
constexpr int kBins = 36;
constexpr double kBinWidthDeg = 10.0;

// which angle of a sample a panel shows
using AngleOf = std::function<double(const PostureSample&)>;
struct Angle {
  const char* name;
  AngleOf value;
  double low, high;        // axis range, degrees
  double tick_step;        // on a tall scatter plot
  double panel_tick_step;  // on a small panel
};
const Angle kAlpha{
    "alpha (about Z)", [](const PostureSample& s) { return s.alpha_deg; }, -180, 180, 45, 90};
const Angle kBeta{
    "beta (about Y)", [](const PostureSample& s) { return s.beta_deg; }, -90, 90, 30, 30};
const Angle kGamma{
    "gamma (about X)", [](const PostureSample& s) { return s.gamma_deg; }, -180, 180, 45, 90};

// a plotting area in pixels and the data range it shows
struct Axes {
  cv::Rect area;
  double x_low, x_high, y_low, y_high;

  cv::Point Map(double x, double y) const {
    const double px = area.x + (x - x_low) / (x_high - x_low) * area.width;
    const double py = area.y + area.height - (y - y_low) / (y_high - y_low) * area.height;
    return cv::Point(static_cast<int>(std::lround(px)), static_cast<int>(std::lround(py)));
  }
};

void PutText(cv::Mat& image, const std::string& text, cv::Point origin, double scale = kTextScale,
             const cv::Scalar& colour = kBlack) {
  cv::putText(image, text, origin, kFont, scale, colour, 1, cv::LINE_AA);
}

cv::Size TextSize(const std::string& text, double scale = kTextScale) {
  int baseline = 0;
  return cv::getTextSize(text, kFont, scale, 1, &baseline);
}

// text centred horizontally on `x`, its baseline at `y`
void PutCentred(cv::Mat& image, const std::string& text, int x, int y, double scale = kTextScale) {
  PutText(image, text, cv::Point(x - TextSize(text, scale).width / 2, y), scale);
}

// text turned 90 degrees counter-clockwise, centred vertically on `y`, its left edge at `x`
void PutVertical(cv::Mat& image, const std::string& text, int x, int y) {
  const cv::Size size = TextSize(text);
  cv::Mat strip(size.height + 8, size.width + 4, image.type(), kWhite);
  PutText(strip, text, cv::Point(2, size.height + 2));
  cv::Mat turned;
  cv::rotate(strip, turned, cv::ROTATE_90_COUNTERCLOCKWISE);
  const cv::Rect target(x, y - turned.rows / 2, turned.cols, turned.rows);
  if ((target & cv::Rect(0, 0, image.cols, image.rows)) == target) turned.copyTo(image(target));
}

// a tick label: no decimals for steps of 1 and more, else as many as the step needs
std::string TickLabel(double value, double step) {
  const int decimals = step >= 1.0 ? 0 : static_cast<int>(std::ceil(-std::log10(step) - 1e-9));
  char text[32];
  std::snprintf(text, sizeof(text), "%.*f", decimals, std::fabs(value) < 1e-12 ? 0.0 : value);
  return text;
}

// a step of 1, 2 or 5 times a power of ten giving about `target` ticks over `range`
double NiceStep(double range, int target) {
  const double raw = range / target;
  const double power = std::pow(10.0, std::floor(std::log10(raw)));
  for (const double factor : {1.0, 2.0, 5.0, 10.0}) {
    if (factor * power >= raw) return factor * power;
  }
  return 10.0 * power;
}

// the frame, grid, tick labels and axis labels of `axes`; `x_step` 0 draws no x ticks
void DrawAxes(cv::Mat& image, const Axes& axes, double x_step, double y_step,
              const std::string& x_label, const std::string& y_label, const std::string& title) {
  const cv::Rect& area = axes.area;
  // grid and tick labels
  if (x_step > 0.0) {
    for (double x = std::ceil(axes.x_low / x_step - 1e-9) * x_step; x <= axes.x_high + 1e-9;
         x += x_step) {
      const cv::Point top = axes.Map(x, axes.y_high), bottom = axes.Map(x, axes.y_low);
      cv::line(image, top, bottom, kGrid, 1);
      cv::line(image, bottom, bottom + cv::Point(0, 5), kBlack, 1);
      PutCentred(image, TickLabel(x, x_step), bottom.x, bottom.y + 20);
    }
  }
  for (double y = std::ceil(axes.y_low / y_step - 1e-9) * y_step; y <= axes.y_high + 1e-9;
       y += y_step) {
    const cv::Point left = axes.Map(axes.x_low, y), right = axes.Map(axes.x_high, y);
    cv::line(image, left, right, kGrid, 1);
    cv::line(image, left, left - cv::Point(5, 0), kBlack, 1);
    const std::string label = TickLabel(y, y_step);
    PutText(image, label, cv::Point(left.x - 8 - TextSize(label).width, left.y + 5));
  }
  // frame and labels
  cv::rectangle(image, area, kBlack, 1);
  PutCentred(image, x_label, area.x + area.width / 2, area.y + area.height + 42);
  PutVertical(image, y_label, std::max(2, area.x - 75), area.y + area.height / 2);
  PutText(image, title, cv::Point(area.x, area.y - 12), kTitleScale);
}

// a colour swatch and label per series, right-aligned above the plotting area
void DrawLegend(cv::Mat& image, const cv::Rect& area, const std::vector<PlotSeries>& series) {
  int y = area.y - 12 - 18 * (static_cast<int>(series.size()) - 1);
  for (size_t s = 0; s < series.size(); ++s, y += 18) {
    const int width = TextSize(series[s].label).width;
    const int x = area.x + area.width - width;
    cv::rectangle(image, cv::Rect(x - 18, y - 10, 12, 12), kSeriesColours[s % 2], cv::FILLED);
    PutText(image, series[s].label, cv::Point(x, y));
  }
}

// the relative frequency (percent) of each 10-degree bin of (-180, 180]
std::vector<double> HistogramPercent(const std::vector<PostureSample>& samples,
                                     const AngleOf& angle) {
  std::vector<double> percent(kBins, 0.0);
  if (samples.empty()) return percent;
  for (const PostureSample& sample : samples) {
    const double value = angle(sample);
    const int bin =
        std::clamp(static_cast<int>(std::floor((value + 180.0) / kBinWidthDeg)), 0, kBins - 1);
    percent[bin] += 100.0;
  }
  for (double& value : percent) value /= static_cast<double>(samples.size());
  return percent;
}

cv::Mat ScatterFigure(const std::vector<PlotSeries>& series, const Angle& y_angle,
                      const std::string& file_title) {
  cv::Mat image(760, 820, CV_8UC3, kWhite);
  const int legend_height = 18 * static_cast<int>(series.size());
  const Axes axes{cv::Rect(95, 50 + legend_height, 700, 640 - legend_height), kBeta.low, kBeta.high,
                  y_angle.low, y_angle.high};
  DrawAxes(image, axes, kBeta.tick_step, y_angle.tick_step, "beta, degrees (about Y)",
           std::string(y_angle.name) + ", degrees", file_title);
  DrawLegend(image, axes.area, series);
  // each series on a layer of its own, blended so dense regions of both stay visible
  for (size_t s = 0; s < series.size(); ++s) {
    cv::Mat layer = image.clone();
    for (const PostureSample& sample : *series[s].samples) {
      cv::circle(layer, axes.Map(sample.beta_deg, y_angle.value(sample)), 2, kSeriesColours[s % 2],
                 cv::FILLED, cv::LINE_AA);
    }
    cv::addWeighted(layer, 0.6, image, 0.4, 0.0, image);
  }
  cv::rectangle(image, axes.area, kBlack, 1);
  return image;
}

cv::Mat HistogramFigure(const std::vector<PlotSeries>& series) {
  cv::Mat image(470, 1500, CV_8UC3, kWhite);
  const int legend_height = 18 * static_cast<int>(series.size());
  PutText(image, "Relative frequency of the posture angles, 10-degree bins", cv::Point(20, 24),
          kTitleScale);
  int left = 95;
  for (const Angle* angle : {&kAlpha, &kBeta, &kGamma}) {
    // the tallest bar sets the y range
    std::vector<std::vector<double>> percent;
    double highest = 1.0;
    for (const PlotSeries& one : series) {
      percent.push_back(HistogramPercent(*one.samples, angle->value));
      highest = std::max(highest, *std::max_element(percent.back().begin(), percent.back().end()));
    }
    const double y_step = NiceStep(highest, 5);
    const Axes axes{cv::Rect(left, 60 + legend_height, 400, 330 - legend_height), angle->low,
                    angle->high, 0.0, std::ceil(highest / y_step) * y_step};
    DrawAxes(image, axes, angle->panel_tick_step, y_step, std::string(angle->name) + ", degrees",
             "% of instances", "");
    if (angle == &kGamma) DrawLegend(image, axes.area, series);
    // side-by-side bars in each bin
    const double width = kBinWidthDeg / static_cast<double>(series.size());
    for (size_t s = 0; s < series.size(); ++s) {
      for (int bin = 0; bin < kBins; ++bin) {
        if (percent[s][bin] <= 0.0) continue;
        const double x0 = -180.0 + bin * kBinWidthDeg + s * width;
        if (x0 < angle->low || x0 >= angle->high) continue;
        const cv::Point top_left = axes.Map(x0, percent[s][bin]);
        const cv::Point bottom_right = axes.Map(x0 + width, 0.0);
        cv::rectangle(image, cv::Rect(top_left, bottom_right - cv::Point(1, 0)),
                      kSeriesColours[s % 2], cv::FILLED);
      }
    }
    cv::rectangle(image, axes.area, kBlack, 1);
    left += 490;
  }
  return image;
}

cv::Mat CumulativeFigure(const std::vector<PlotSeries>& series) {
  cv::Mat image(470, 1500, CV_8UC3, kWhite);
  const int legend_height = 18 * static_cast<int>(series.size());
  PutText(image, "Cumulative frequency of the posture angles", cv::Point(20, 24), kTitleScale);
  int left = 95;
  for (const Angle* angle : {&kAlpha, &kBeta, &kGamma}) {
    const Axes axes{cv::Rect(left, 60 + legend_height, 400, 330 - legend_height), angle->low,
                    angle->high, 0.0, 1.0};
    DrawAxes(image, axes, angle->panel_tick_step, 0.2, std::string(angle->name) + ", degrees",
             "cumulative frequency", "");
    if (angle == &kGamma) DrawLegend(image, axes.area, series);
    // the empirical CDF as a step line
    for (size_t s = 0; s < series.size(); ++s) {
      std::vector<double> values;
      for (const PostureSample& sample : *series[s].samples) values.push_back(angle->value(sample));
      if (values.empty()) continue;
      std::sort(values.begin(), values.end());
      std::vector<cv::Point> line = {axes.Map(angle->low, 0.0)};
      const double n = static_cast<double>(values.size());
      for (size_t k = 0; k < values.size(); ++k) {
        line.push_back(axes.Map(values[k], k / n));
        line.push_back(axes.Map(values[k], (k + 1) / n));
      }
      line.push_back(axes.Map(angle->high, 1.0));
      cv::polylines(image, line, false, kSeriesColours[s % 2], 2, cv::LINE_AA);
    }
    left += 490;
  }
  return image;
}

cv::Mat FacesFigure(const std::vector<PlotSeries>& series) {
  // the faces seen, and whether any is unknown
  int highest_face = -1;
  bool any_unknown = false;
  for (const PlotSeries& one : series) {
    for (const PostureSample& sample : *one.samples) {
      highest_face = std::max(highest_face, sample.resting_face);
      any_unknown = any_unknown || sample.resting_face < 0;
    }
  }
  const int categories = highest_face + 1 + (any_unknown ? 1 : 0);
  const int area_width = std::clamp(40 * std::max(categories, 1), 400, 1400);
  cv::Mat image(470, area_width + 140, CV_8UC3, kWhite);
  const int legend_height = 18 * static_cast<int>(series.size());

  // percent per category (the unknown last)
  std::vector<std::vector<double>> percent;
  double highest = 1.0;
  for (const PlotSeries& one : series) {
    std::vector<double> share(static_cast<size_t>(std::max(categories, 1)), 0.0);
    for (const PostureSample& sample : *one.samples) {
      share[sample.resting_face >= 0 ? sample.resting_face : categories - 1] += 100.0;
    }
    for (double& value : share) value /= std::max<double>(1.0, one.samples->size());
    highest = std::max(highest, *std::max_element(share.begin(), share.end()));
    percent.push_back(share);
  }
  const double y_step = NiceStep(highest, 5);
  const Axes axes{cv::Rect(95, 60 + legend_height, area_width, 330 - legend_height), 0.0,
                  static_cast<double>(std::max(categories, 1)), 0.0,
                  std::ceil(highest / y_step) * y_step};
  DrawAxes(image, axes, 0.0, y_step, "resting face (0 = largest hull face)", "% of instances",
           "Resting faces");
  DrawLegend(image, axes.area, series);
  if (categories == 0) {
    PutCentred(image, "no instances", axes.area.x + axes.area.width / 2,
               axes.area.y + axes.area.height / 2);
  }

  // category labels and side-by-side bars
  const double width = 0.8 / static_cast<double>(series.size());
  for (int c = 0; c < categories; ++c) {
    const bool unknown = any_unknown && c == categories - 1;
    const cv::Point base = axes.Map(c + 0.5, 0.0);
    PutCentred(image, unknown ? "unknown" : std::to_string(c), base.x, base.y + 20);
    for (size_t s = 0; s < series.size(); ++s) {
      if (percent[s][c] <= 0.0) continue;
      const double x0 = c + 0.1 + s * width;
      cv::rectangle(image, cv::Rect(axes.Map(x0, percent[s][c]), axes.Map(x0 + width, 0.0)),
                    kSeriesColours[s % 2], cv::FILLED);
    }
  }
  cv::rectangle(image, axes.area, kBlack, 1);
  return image;
}

// writes `image` as PNG to `path` through a temporary name
void WritePng(const cv::Mat& image, const std::string& path) {
  std::vector<uchar> bytes;
  if (!cv::imencode(".png", image, bytes)) throw std::runtime_error("cannot encode " + path);
  const std::string temporary = path + ".tmp";
  {
    std::ofstream file(temporary, std::ios::binary | std::ios::trunc);
    file.write(reinterpret_cast<const char*>(bytes.data()),
               static_cast<std::streamsize>(bytes.size()));
    file.close();
    if (!file) throw std::runtime_error("cannot write " + temporary);
  }
  std::error_code error;
  fs::rename(temporary, path, error);
  if (error)
    throw std::runtime_error("cannot rename " + temporary + " to " + path + ": " + error.message());
}

}  // namespace

std::vector<std::string> PlotFileNames() {
  return {"scatter_beta_alpha.png", "scatter_beta_gamma.png", "histograms.png", "cumulative.png",
          "faces.png"};
}

std::vector<std::string> WritePlots(const std::string& dir, const std::vector<PlotSeries>& series) {
  std::error_code error;
  fs::create_directories(dir, error);
  if (error || !fs::is_directory(dir)) {
    throw std::runtime_error("cannot create the folder " + dir +
                             (error ? ": " + error.message() : std::string()));
  }
  const std::vector<cv::Mat> figures = {
      ScatterFigure(series, kAlpha, "Posture: beta against alpha"),
      ScatterFigure(series, kGamma, "Posture: beta against gamma"), HistogramFigure(series),
      CumulativeFigure(series), FacesFigure(series)};
  const std::vector<std::string> names = PlotFileNames();
  std::vector<std::string> paths;
  for (size_t k = 0; k < figures.size(); ++k) {
    paths.push_back((fs::path(dir) / names[k]).string());
    WritePng(figures[k], paths.back());
  }
  return paths;
}

}  // namespace stackgen::stats
