#include "fslam/core/eval/trajectory_plot.hpp"

#include "fslam/core/error.hpp"

#include <algorithm>
#include <cmath>
#include <iomanip>
#include <sstream>
#include <vector>

#include <Eigen/Eigenvalues>
#include <opencv2/core.hpp>
#include <opencv2/imgproc.hpp>

namespace fslam::core {
namespace {

// Drawing happens in OpenCV's BGR order; the result is converted to RGB at the end.
const cv::Scalar kWhite(255, 255, 255);
const cv::Scalar kInk(40, 40, 40);
const cv::Scalar kGrid(232, 232, 232);
const cv::Scalar kFrame(150, 150, 150);
const cv::Scalar kGroundTruth(90, 90, 90);
constexpr int kFont = cv::FONT_HERSHEY_SIMPLEX;
constexpr int kShift = 4;  // sub-pixel bits for cv::line / cv::circle
constexpr double kSub = 1 << kShift;

std::string fixed(double value, int decimals, bool sign = false) {
  std::ostringstream out;
  if (sign) out << std::showpos;
  out << std::fixed << std::setprecision(decimals) << value;
  return out.str();
}

// `digits` significant digits, trailing zeros kept (printf's %#.Ng).
std::string significant(double value, int digits) {
  std::ostringstream out;
  out << std::showpoint << std::setprecision(digits) << value;
  return out.str();
}

// 1, 2 or 5 times a power of ten, close to `target`.
double nice_step(double target) {
  const double p = std::pow(10.0, std::floor(std::log10(target)));
  const double f = target / p;
  return (f < 1.5 ? 1.0 : f < 3.5 ? 2.0 : f < 7.5 ? 5.0 : 10.0) * p;
}

// Decimals that show tick values `step` apart without trailing noise.
int tick_decimals(double step) {
  return step >= 1.0 ? 0 : static_cast<int>(std::ceil(-std::log10(step) - 1e-9));
}

void text(cv::Mat& img, const std::string& s, cv::Point origin, double scale,
          const cv::Scalar& colour = kInk, int thickness = 1) {
  cv::putText(img, s, origin, kFont, scale, colour, thickness, cv::LINE_AA);
}

cv::Size text_size(const std::string& s, double scale, int thickness = 1) {
  int baseline = 0;
  return cv::getTextSize(s, kFont, scale, thickness, &baseline);
}

// Text turned 90 degrees counter-clockwise (reads bottom to top), centred on `centre`.
void vertical_text(cv::Mat& img, const std::string& s, cv::Point centre, double scale) {
  const cv::Size size = text_size(s, scale);
  cv::Mat strip(size.height + 8, size.width + 4, CV_8UC3, kWhite);
  text(strip, s, {2, size.height + 2}, scale);
  cv::Mat turned;
  cv::rotate(strip, turned, cv::ROTATE_90_COUNTERCLOCKWISE);
  const cv::Rect roi(centre.x - turned.cols / 2, centre.y - turned.rows / 2, turned.cols,
                     turned.rows);
  if ((roi & cv::Rect(0, 0, img.cols, img.rows)) != roi) return;
  cv::Mat target = img(roi);
  cv::min(target, turned, target);  // dark ink over whatever is there
}

cv::Point sub(const cv::Point2d& p) {
  return {static_cast<int>(std::lround(p.x * kSub)), static_cast<int>(std::lround(p.y * kSub))};
}

// Turbo colour map, 256 BGR entries.
std::vector<cv::Vec3b> colour_lut() {
  cv::Mat ramp(256, 1, CV_8UC1);
  for (int i = 0; i < 256; ++i) ramp.at<uchar>(i) = static_cast<uchar>(i);
  cv::Mat coloured;
  cv::applyColorMap(ramp, coloured, cv::COLORMAP_TURBO);
  std::vector<cv::Vec3b> lut(256);
  for (int i = 0; i < 256; ++i) lut[static_cast<std::size_t>(i)] = coloured.at<cv::Vec3b>(i);
  return lut;
}

cv::Scalar colour_of(const std::vector<cv::Vec3b>& lut, double fraction) {
  const int i = static_cast<int>(std::lround(std::clamp(fraction, 0.0, 1.0) * 255.0));
  const cv::Vec3b c = lut[static_cast<std::size_t>(i)];
  return {static_cast<double>(c[0]), static_cast<double>(c[1]), static_cast<double>(c[2])};
}

// Consecutive samples further apart in time than this are not joined by a line.
double gap_threshold(const std::vector<double>& stamps) {
  if (stamps.size() < 2) return 0.0;
  std::vector<double> dt;
  for (std::size_t i = 1; i < stamps.size(); ++i) dt.push_back(stamps[i] - stamps[i - 1]);
  std::nth_element(dt.begin(), dt.begin() + static_cast<long>(dt.size() / 2), dt.end());
  return std::max(1.0, 10.0 * dt[dt.size() / 2]);  // seconds
}

// The colour scale spans at least 1 mm, so sub-millimetre noise (e.g. an estimate equal to the
// ground truth) reads as "no error" instead of being stretched over the whole scale.
constexpr double kMinColourRange = 1e-3;  // metres

// Error unit for the colour bar, chosen so the ticks read as small whole numbers.
struct ErrorUnit {
  double per_metre;
  const char* name;
};
ErrorUnit error_unit(double max_error_m) {
  if (max_error_m < 0.01) return {1000.0, "mm"};
  if (max_error_m < 1.0) return {100.0, "cm"};
  return {1.0, "m"};
}

// One view: world-to-pixel mapping of two plane coordinates (metres) into a plot rectangle.
struct View {
  cv::Rect area;       // plot rectangle, pixels
  double centre_u = 0.0, centre_v = 0.0;  // metres at the rectangle's centre
  double px_per_m = 1.0;
  cv::Point2d to_px(double a, double b) const {
    return {area.x + 0.5 * area.width + (a - centre_u) * px_per_m,
            area.y + 0.5 * area.height - (b - centre_v) * px_per_m};
  }
};

void draw_axes(cv::Mat& img, const View& view, const std::string& u_label,
               const std::string& v_label) {
  const double visible_u = view.area.width / view.px_per_m;
  const double step = nice_step(visible_u / 6.0);
  const int decimals = tick_decimals(step);
  const double u0 = view.centre_u - 0.5 * view.area.width / view.px_per_m;
  const double u1 = view.centre_u + 0.5 * view.area.width / view.px_per_m;
  const double v0 = view.centre_v - 0.5 * view.area.height / view.px_per_m;
  const double v1 = view.centre_v + 0.5 * view.area.height / view.px_per_m;
  const int bottom = view.area.y + view.area.height;
  for (double u = std::ceil(u0 / step) * step; u <= u1; u += step) {
    const int x = static_cast<int>(std::lround(view.to_px(u, 0.0).x));
    cv::line(img, {x, view.area.y}, {x, bottom}, kGrid, 1);
    cv::line(img, {x, bottom}, {x, bottom + 5}, kFrame, 1);
    const std::string label = fixed(std::abs(u) < 0.5 * step ? 0.0 : u, decimals);
    text(img, label, {x - text_size(label, 0.42).width / 2, bottom + 20}, 0.42);
  }
  for (double v = std::ceil(v0 / step) * step; v <= v1; v += step) {
    const int y = static_cast<int>(std::lround(view.to_px(0.0, v).y));
    cv::line(img, {view.area.x, y}, {view.area.x + view.area.width, y}, kGrid, 1);
    cv::line(img, {view.area.x - 5, y}, {view.area.x, y}, kFrame, 1);
    const std::string label = fixed(std::abs(v) < 0.5 * step ? 0.0 : v, decimals);
    text(img, label, {view.area.x - 9 - text_size(label, 0.42).width, y + 5}, 0.42);
  }
  cv::rectangle(img, view.area, kFrame, 1);
  text(img, u_label, {view.area.x + view.area.width / 2 - text_size(u_label, 0.5).width / 2,
                      bottom + 44}, 0.5);
  vertical_text(img, v_label, {view.area.x - 52, view.area.y + view.area.height / 2}, 0.5);
}

void draw_scale_bar(cv::Mat& img, const View& view) {
  const double length_m = nice_step(0.2 * view.area.width / view.px_per_m);
  const int length_px = static_cast<int>(std::lround(length_m * view.px_per_m));
  const int x0 = view.area.x + 16, y = view.area.y + view.area.height - 18;
  const std::string label = fixed(length_m, tick_decimals(length_m)) + " m";
  const cv::Size size = text_size(label, 0.45);
  cv::rectangle(img, {x0 - 6, y - size.height - 14}, {x0 + std::max(length_px, size.width) + 6, y + 8},
                kWhite, cv::FILLED);
  cv::line(img, {x0, y}, {x0 + length_px, y}, kInk, 3);
  cv::line(img, {x0, y - 5}, {x0, y + 5}, kInk, 1);
  cv::line(img, {x0 + length_px, y - 5}, {x0 + length_px, y + 5}, kInk, 1);
  text(img, label, {x0 + length_px / 2 - size.width / 2, y - 9}, 0.45);
}

// Principal axes of the ground-truth positions: axis 1 the largest spread, axis 3 the smallest
// (the normal of a mostly planar path). Axes 1 and 3 point along their largest world component,
// so world "up" stays up in the side view when it is axis 3; axis 2 = 3 x 1 keeps the frame
// right-handed, so neither view is mirrored. Rows: axis 1, 2, 3 in world coordinates.
Eigen::Matrix3d principal_axes(const Trajectory& gt, Eigen::Vector3d* centroid_out) {
  Eigen::Vector3d centroid = Eigen::Vector3d::Zero();
  for (const auto& pose : gt) centroid += pose.T_world_camera.translation();
  centroid /= static_cast<double>(gt.size());
  Eigen::Matrix3d covariance = Eigen::Matrix3d::Zero();
  for (const auto& pose : gt) {
    const Eigen::Vector3d d = pose.T_world_camera.translation() - centroid;
    covariance += d * d.transpose();
  }
  const Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> eigen(covariance);  // ascending
  auto dominant_positive = [](Eigen::Vector3d e) {
    Eigen::Index dominant = 0;
    e.cwiseAbs().maxCoeff(&dominant);
    return e(dominant) < 0.0 ? Eigen::Vector3d(-e) : e;
  };
  const Eigen::Vector3d axis1 = dominant_positive(eigen.eigenvectors().col(2));
  const Eigen::Vector3d axis3 = dominant_positive(eigen.eigenvectors().col(0));
  Eigen::Matrix3d axes;
  axes.row(0) = axis1.transpose();
  axes.row(1) = axis3.cross(axis1).transpose();
  axes.row(2) = axis3.transpose();
  *centroid_out = centroid;
  return axes;
}

// The plot's layout, pixels.
struct Layout {
  int P;  // panel size
  int title_h = 64, legend_h = 64, bar_w = 150;
  int margin_l = 78, margin_r = 22, margin_t = 40, margin_b = 62;
  int plot_w() const { return P - margin_l - margin_r; }
  int plot_h() const { return P - margin_t - margin_b; }
};

// What the drawing steps share: the ground truth and aligned estimate in principal-axis
// coordinates, their time stamps, the colour scale and unit.
struct PlotData {
  std::vector<Eigen::Vector3d> g, e;  // [gt.size()], [ate.pairs]
  std::vector<double> gt_stamps, pair_stamps;
  double colour_max = 0.0;            // metres at the top of the colour scale
  ErrorUnit unit{};
  std::vector<cv::Vec3b> lut;
};

// The top and side views over the same metres per pixel, centred on the points' bounding box.
void make_views(const Layout& layout, const PlotData& data, View views[2]) {
  Eigen::Vector3d lo = data.g.front(), hi = data.g.front();
  for (const auto* set : {&data.g, &data.e})
    for (const auto& p : *set) {
      lo = lo.cwiseMin(p);
      hi = hi.cwiseMax(p);
    }
  const Eigen::Vector3d extent = (hi - lo).cwiseMax(Eigen::Vector3d::Constant(1e-3));
  const int P = layout.P, plot_w = layout.plot_w(), plot_h = layout.plot_h();
  const double px_per_m =
      0.92 * std::min({plot_w / extent.x(), plot_h / extent.y(), plot_h / extent.z()});
  for (int k = 0; k < 2; ++k) {
    views[k].area = cv::Rect(k * P + layout.margin_l, layout.title_h + layout.margin_t, plot_w, plot_h);
    views[k].px_per_m = px_per_m;
    views[k].centre_u = 0.5 * (lo.x() + hi.x());
    views[k].centre_v = k == 0 ? 0.5 * (lo.y() + hi.y()) : 0.5 * (lo.z() + hi.z());
  }
}

void draw_title(cv::Mat& img, const TrajectoryPlotConfig& config, const AteResult& ate, const ErrorUnit& unit) {
  std::string title = config.title.empty() ? std::string() : config.title + "  -  ";
  // Below a nanometre the error is floating-point noise: say 0.
  const std::string rmse_text = ate.rmse < 1e-9 ? "0" : significant(ate.rmse * unit.per_metre, 4);
  title += "ATE RMSE " + rmse_text + " " + unit.name + " (" +
           to_string(ate.alignment) + ", " + std::to_string(ate.pairs) + " pairs)";
  double title_scale = 0.8;
  while (title_scale > 0.4 && text_size(title, title_scale, 2).width > img.cols - 40)
    title_scale -= 0.05;
  text(img, title, {img.cols / 2 - text_size(title, title_scale, 2).width / 2, 42}, title_scale,
       kInk, 2);
}

// One view's paths: the ground truth in grey, the estimate coloured by its ATE error (dots too
// when sparse), the start circled, then the frame and scale bar.
void draw_paths(cv::Mat& img, const View& view, int k, const PlotData& data, const AteResult& ate,
                double gt_gap, double pair_gap, bool sparse) {
  const int b = k == 0 ? 1 : 2;  // second plane coordinate
  cv::Mat canvas = img(view.area);  // drawing into the sub-image clips to the plot rectangle
  const cv::Point2d origin(view.area.x, view.area.y);
  auto px = [&](const Eigen::Vector3d& p) { return view.to_px(p.x(), p(b)) - origin; };
  const auto& g = data.g;
  const auto& e = data.e;
  for (std::size_t i = 1; i < g.size(); ++i)
    if (data.gt_stamps[i] - data.gt_stamps[i - 1] <= gt_gap)
      cv::line(canvas, sub(px(g[i - 1])), sub(px(g[i])), kGroundTruth, 2, cv::LINE_AA, kShift);
  for (std::size_t i = 1; i < e.size(); ++i)
    if (data.pair_stamps[i] - data.pair_stamps[i - 1] <= pair_gap)
      cv::line(canvas, sub(px(e[i - 1])), sub(px(e[i])),
               colour_of(data.lut, 0.5 * (ate.errors[i - 1] + ate.errors[i]) / data.colour_max), 2,
               cv::LINE_AA, kShift);
  if (sparse)
    for (std::size_t i = 0; i < e.size(); ++i)
      cv::circle(canvas, sub(px(e[i])), static_cast<int>(3.5 * kSub),
                 colour_of(data.lut, ate.errors[i] / data.colour_max), cv::FILLED, cv::LINE_AA, kShift);
  cv::circle(canvas, sub(px(g.front())), static_cast<int>(6 * kSub), kInk, 2, cv::LINE_AA,
             kShift);
  cv::rectangle(img, view.area, kFrame, 1);
  draw_scale_bar(img, view);
}

// Colour bar with ticks in the chosen error unit.
void draw_colour_bar(cv::Mat& img, const Layout& layout, const PlotData& data, const AteResult& ate) {
  const int bar_x = 2 * layout.P + 28, bar_top = layout.title_h + layout.margin_t + 40;
  const int bar_h = layout.plot_h() - 60;
  const std::string bar_title = "ATE error";
  const std::string bar_unit = std::string("[") + data.unit.name + "]";
  text(img, bar_title, {bar_x - 8, bar_top - 30}, 0.5);
  text(img, bar_unit, {bar_x - 8, bar_top - 10}, 0.5);
  for (int y = 0; y < bar_h; ++y) {
    const cv::Scalar c = colour_of(data.lut, 1.0 - static_cast<double>(y) / (bar_h - 1));
    cv::line(img, {bar_x, bar_top + y}, {bar_x + 22, bar_top + y}, c, 1);
  }
  cv::rectangle(img, {bar_x, bar_top}, {bar_x + 22, bar_top + bar_h - 1}, kFrame, 1);
  const double max_display = data.colour_max * data.unit.per_metre;
  const double tick = nice_step(max_display / 5.0);
  for (double t = 0.0; t <= max_display + 1e-9 * max_display; t += tick) {
    const int y = bar_top + bar_h - 1 - static_cast<int>(std::lround(t / max_display * (bar_h - 1)));
    cv::line(img, {bar_x + 22, y}, {bar_x + 28, y}, kInk, 1);
    text(img, fixed(t, tick_decimals(tick)), {bar_x + 32, y + 5}, 0.42);
  }
  const std::string max_label =
      "max " + (ate.max < 1e-9 ? std::string("0") : significant(ate.max * data.unit.per_metre, 3));
  text(img, max_label, {bar_x - 8, bar_top + bar_h + 24}, 0.42);
}

// Legend and axis definitions.
void draw_legend(cv::Mat& img, const Layout& layout, const PlotData& data, const AteResult& ate,
                 const Eigen::Matrix3d& axes) {
  const int legend_y = layout.title_h + layout.P + 18;
  int x = layout.margin_l;
  cv::line(img, {x, legend_y - 5}, {x + 36, legend_y - 5}, kGroundTruth, 2, cv::LINE_AA);
  x += 44;
  text(img, "ground truth", {x, legend_y}, 0.5);
  x += text_size("ground truth", 0.5).width + 30;
  for (int s = 0; s < 36; ++s)
    cv::line(img, {x + s, legend_y - 5}, {x + s + 1, legend_y - 5},
             colour_of(data.lut, s / 35.0), 3, cv::LINE_AA);
  x += 44;
  const std::string est_label = std::string("estimate, aligned with ") + to_string(ate.alignment) +
                                (ate.alignment == Alignment::kSim3
                                     ? " (scale " + significant(ate.scale, 4) + ")"
                                     : std::string()) +
                                ", coloured by ATE error";
  text(img, est_label, {x, legend_y}, 0.5);
  x += text_size(est_label, 0.5).width + 30;
  cv::circle(img, {x + 6, legend_y - 5}, 6, kInk, 2, cv::LINE_AA);
  text(img, "start", {x + 20, legend_y}, 0.5);

  auto axis_text = [&](int k) {
    const Eigen::Vector3d a = axes.row(k).transpose();
    return std::to_string(k + 1) + " = (" + fixed(a.x(), 2, true) + ", " + fixed(a.y(), 2, true) +
           ", " + fixed(a.z(), 2, true) + ")";
  };
  const std::string axes_line = "axes: principal axes of the ground-truth positions in world "
                                "coordinates (x, y, z), origin at their centroid:  " +
                                axis_text(0) + ",  " + axis_text(1) + ",  " + axis_text(2);
  text(img, axes_line, {layout.margin_l, legend_y + 28}, 0.42, cv::Scalar(100, 100, 100));
}

}  // namespace

bool validate(const TrajectoryPlotConfig& config, std::string* why) {
  if (config.panel_size < 300 || config.panel_size > 4000)
    return fail(why, "trajectory plot panel_size must be 300..4000 pixels, got " +
                         std::to_string(config.panel_size));
  return true;
}

bool render_trajectory_plot(const Trajectory& gt, const AteResult& ate,
                            const TrajectoryPlotConfig& config, cv::Mat* rgb, std::string* why) {
  if (!validate(config, why)) return false;
  if (ate.pairs == 0 || ate.est_aligned.size() != ate.pairs || ate.errors.size() != ate.pairs ||
      ate.gt_indices.size() != ate.pairs)
    return fail(why, "trajectory plot: the ATE result holds no aligned poses");
  for (std::size_t i : ate.gt_indices)
    if (i >= gt.size())
      return fail(why, "trajectory plot: the ATE result was computed on another ground truth");

  Eigen::Vector3d centroid;
  const Eigen::Matrix3d axes = principal_axes(gt, &centroid);
  PlotData data;
  data.g.resize(gt.size());
  data.e.resize(ate.pairs);
  for (std::size_t i = 0; i < gt.size(); ++i)
    data.g[i] = axes * (gt[i].T_world_camera.translation() - centroid);
  for (std::size_t i = 0; i < ate.pairs; ++i) data.e[i] = axes * (ate.est_aligned[i] - centroid);

  const Layout layout{config.panel_size};
  cv::Mat img(layout.title_h + layout.P + layout.legend_h, 2 * layout.P + layout.bar_w, CV_8UC3, kWhite);
  View views[2];
  make_views(layout, data, views);

  data.colour_max = std::max(ate.max, kMinColourRange);
  data.unit = error_unit(data.colour_max);
  draw_title(img, config, ate, data.unit);

  const char* names[2] = {"top view (axes 1-2)", "side view (axes 1-3)"};
  const char* v_labels[2] = {"axis 2 [m]", "axis 3 [m]"};
  for (int k = 0; k < 2; ++k) {
    draw_axes(img, views[k], "axis 1 [m]", v_labels[k]);
    const std::string name = names[k];
    text(img, name,
         {views[k].area.x + views[k].area.width / 2 - text_size(name, 0.6).width / 2,
          views[k].area.y - 14},
         0.6);
  }

  data.lut = colour_lut();
  data.gt_stamps.resize(gt.size());
  data.pair_stamps.resize(ate.pairs);
  for (std::size_t i = 0; i < gt.size(); ++i) data.gt_stamps[i] = gt[i].timestamp;
  for (std::size_t i = 0; i < ate.pairs; ++i) data.pair_stamps[i] = gt[ate.gt_indices[i]].timestamp;
  const double gt_gap = gap_threshold(data.gt_stamps), pair_gap = gap_threshold(data.pair_stamps);
  const bool sparse = ate.pairs < 400;
  for (int k = 0; k < 2; ++k) draw_paths(img, views[k], k, data, ate, gt_gap, pair_gap, sparse);

  draw_colour_bar(img, layout, data, ate);
  draw_legend(img, layout, data, ate, axes);
  cv::cvtColor(img, *rgb, cv::COLOR_BGR2RGB);
  return true;
}

}  // namespace fslam::core
