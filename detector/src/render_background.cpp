#include "render_background.hpp"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <numbers>
#include <opencv2/core.hpp>
#include <opencv2/imgproc.hpp>
#include <stdexcept>
#include <string>
#include <string_view>
#include <utility>
#include <vector>

#include "render_random.hpp"

namespace markerd::detector {
namespace {

constexpr std::array<Background, 7> kBackgrounds{Background::shapes,       Background::tiles,   Background::keyboard,
                                                 Background::checkerboard, Background::windows, Background::text,
                                                 Background::outlets};
constexpr std::array<std::pair<Background, std::string_view>, 7> kBackgroundNames{{
    {Background::shapes, "shapes"},
    {Background::tiles, "tiles"},
    {Background::keyboard, "keyboard"},
    {Background::checkerboard, "checkerboard"},
    {Background::windows, "windows"},
    {Background::text, "text"},
    {Background::outlets, "outlets"},
}};

}  // namespace

std::span<const Background> all_backgrounds() { return kBackgrounds; }

std::string_view to_string(Background background) {
  for (const auto& [kind, name] : kBackgroundNames) {
    if (kind == background) return name;
  }
  throw std::logic_error("to_string: unknown background");
}

std::optional<Background> background_from_string(std::string_view name) {
  for (const auto& [kind, known] : kBackgroundNames) {
    if (known == name) return kind;
  }
  return std::nullopt;
}

namespace render {
namespace {

double deg(double d) { return d * std::numbers::pi / 180.0; }

// ---------------------------------------------------------------- shapes

struct Drawer {
  cv::Mat& img;
  Random& rng;
  double scale;  // min(width, height)

  static constexpr int kShift = 4;  // sub-pixel bits for cv's polygon drawing
  static cv::Point fixed(double x, double y) {
    return {static_cast<int>(std::lround(x * (1 << kShift))), static_cast<int>(std::lround(y * (1 << kShift)))};
  }

  double grey() { return rng.uniform(8, 248); }
  cv::Point2d centre() { return {rng.uniform(-0.1, 1.1) * img.cols, rng.uniform(-0.1, 1.1) * img.rows}; }

  // A rectangle (lu0..lu1, lv0..lv1) of a frame centred at c, rotated by `angle`.
  std::array<cv::Point, 4> quad(cv::Point2d c, double angle, double lu0, double lv0, double lu1, double lv1) const {
    const double ca = std::cos(angle), sa = std::sin(angle);
    auto at = [&](double u, double v) { return fixed(c.x + ca * u - sa * v, c.y + sa * u + ca * v); };
    return {at(lu0, lv0), at(lu1, lv0), at(lu1, lv1), at(lu0, lv1)};
  }
  void fill(const std::array<cv::Point, 4>& q, double g) const {
    cv::fillConvexPoly(img, q.data(), 4, cv::Scalar(g), cv::LINE_AA, kShift);
  }

  void filled_rect() {
    const auto c = centre();
    const double w = rng.uniform(0.03, 0.35) * scale, h = rng.uniform(0.03, 0.35) * scale;
    fill(quad(c, rng.uniform(0, std::numbers::pi), -w / 2, -h / 2, w / 2, h / 2), grey());
  }
  void outlined_rect() {
    const auto c = centre();
    const double w = rng.uniform(0.05, 0.4) * scale, h = rng.uniform(0.05, 0.4) * scale;
    const auto q = quad(c, rng.uniform(0, std::numbers::pi), -w / 2, -h / 2, w / 2, h / 2);
    cv::polylines(img, std::vector<cv::Point>(q.begin(), q.end()), true, cv::Scalar(grey()), rng.integer(1, 5),
                  cv::LINE_AA, kShift);
  }
  void ellipse(bool filled) {
    const auto c = centre();
    const cv::Size axes(static_cast<int>(rng.uniform(0.02, 0.2) * scale) + 1,
                        static_cast<int>(rng.uniform(0.02, 0.2) * scale) + 1);
    cv::ellipse(img, cv::Point(static_cast<int>(c.x), static_cast<int>(c.y)), axes, rng.uniform(0, 180), 0, 360,
                cv::Scalar(grey()), filled ? cv::FILLED : rng.integer(1, 4), cv::LINE_AA);
  }
  void line() {
    const auto a = centre(), b = centre();
    cv::line(img, fixed(a.x, a.y), fixed(b.x, b.y), cv::Scalar(grey()), rng.integer(1, 6), cv::LINE_AA, kShift);
  }
  void gradient_patch() {
    const int w = static_cast<int>(rng.uniform(0.05, 0.4) * scale) + 2;
    const int h = static_cast<int>(rng.uniform(0.05, 0.4) * scale) + 2;
    const int x0 = rng.integer(-w / 2, img.cols - w / 2), y0 = rng.integer(-h / 2, img.rows - h / 2);
    const double g0 = grey(), g1 = grey(), angle = rng.uniform(0, 2 * std::numbers::pi);
    const double dx = std::cos(angle), dy = std::sin(angle);
    const double span = std::abs(dx) * w + std::abs(dy) * h;
    for (int y = std::max(0, y0); y < std::min(img.rows, y0 + h); ++y) {
      auto* row = img.ptr<std::uint8_t>(y);
      for (int x = std::max(0, x0); x < std::min(img.cols, x0 + w); ++x) {
        const double s = ((x - x0 - w / 2.0) * dx + (y - y0 - h / 2.0) * dy) / span + 0.5;
        row[x] = cv::saturate_cast<std::uint8_t>(g0 + (g1 - g0) * s);
      }
    }
  }
  // A dark square band around a lighter inside: the shape every square-marker
  // detector starts from, to exercise its rejection.
  void square_frame() {
    const auto c = centre();
    const double side = rng.uniform(0.05, 0.25) * scale;
    const double band = side * rng.uniform(0.08, 0.25);
    const double angle = rng.uniform(0, std::numbers::pi);
    const double h = side / 2;
    fill(quad(c, angle, -h, -h, h, h), rng.uniform(5, 60));
    fill(quad(c, angle, -h + band, -h + band, h - band, h - band), rng.uniform(120, 245));
  }
  // A dark-bordered grid of random cells: looks like a coded marker but
  // carries no valid code (except by rare chance).
  void checker_patch() {
    const auto c = centre();
    const int n = rng.integer(4, 8);
    const double cell = rng.uniform(0.008, 0.035) * scale;
    const double angle = rng.uniform(0, std::numbers::pi);
    const double h = n * cell / 2;
    const double dark = rng.uniform(5, 60), light = rng.uniform(150, 245);
    fill(quad(c, angle, -h - cell, -h - cell, h + cell, h + cell), dark);
    for (int r = 0; r < n; ++r) {
      for (int k = 0; k < n; ++k) {
        if (rng.uniform() < 0.5) continue;
        fill(quad(c, angle, -h + k * cell, -h + r * cell, -h + (k + 1) * cell, -h + (r + 1) * cell), light);
      }
    }
  }
  void text() {
    static constexpr std::string_view chars = "ABCDEFGHKMNPRSTUVXYZ0123456789";
    std::string s;
    const int len = rng.integer(2, 8);
    for (int i = 0; i < len; ++i)
      s += chars[static_cast<std::size_t>(rng.integer(0, static_cast<int>(chars.size()) - 1))];
    const auto c = centre();
    cv::putText(img, s, cv::Point(static_cast<int>(c.x), static_cast<int>(c.y)), cv::FONT_HERSHEY_SIMPLEX,
                rng.uniform(0.4, 2.0) * scale / 480.0, cv::Scalar(grey()), rng.integer(1, 3), cv::LINE_AA);
  }
};

void draw_shapes(cv::Mat& img, Random& rng) {
  Drawer d{img, rng, static_cast<double>(std::min(img.cols, img.rows))};
  const int shapes = rng.integer(30, 50);
  for (int i = 0; i < shapes; ++i) {
    switch (rng.integer(0, 9)) {
      case 0:
      case 1: d.filled_rect(); break;
      case 2: d.outlined_rect(); break;
      case 3: d.ellipse(true); break;
      case 4: d.ellipse(false); break;
      case 5: d.line(); break;
      case 6: d.gradient_patch(); break;
      case 7: d.square_frame(); break;
      case 8: d.checker_patch(); break;
      default: d.text(); break;
    }
  }
}

// ---------------------------------------------------------------- textures
//
// A texture is drawn as the grey its surfaces would have in even light, on
// a canvas whose bare wall is the gradient's mean level; the gradient then
// lights the whole canvas, so that it still falls off across a texture that
// covers the image. Sizes are in `unit`s: pixels of a 480-line image.

constexpr int kShift = Drawer::kShift;

cv::Point fixed(cv::Point2d p) { return Drawer::fixed(p.x, p.y); }

// A place in the image: local (u, v) about `centre`, turned by `angle`.
class Place {
 public:
  Place(cv::Point2d centre, double angle) : centre_(centre), cos_(std::cos(angle)), sin_(std::sin(angle)) {}
  [[nodiscard]] cv::Point2d at(double u, double v) const {
    return {centre_.x + cos_ * u - sin_ * v, centre_.y + sin_ * u + cos_ * v};
  }

 private:
  cv::Point2d centre_;
  double cos_, sin_;
};

struct Rect {
  double u0, v0, u1, v1;
  [[nodiscard]] Rect inset(double d) const { return {u0 + d, v0 + d, u1 - d, v1 - d}; }
  [[nodiscard]] double width() const { return u1 - u0; }
  [[nodiscard]] double height() const { return v1 - v0; }
  [[nodiscard]] double mid_u() const { return (u0 + u1) / 2; }
  [[nodiscard]] double mid_v() const { return (v0 + v1) / 2; }
};

void fill_polygon(cv::Mat& img, const std::vector<cv::Point>& points, double grey) {
  cv::fillConvexPoly(img, points, cv::Scalar(grey), cv::LINE_AA, kShift);
}

void fill_rect(cv::Mat& img, const Place& place, const Rect& r, double grey) {
  if (!(r.u1 > r.u0 && r.v1 > r.v0)) return;
  fill_polygon(img,
               {fixed(place.at(r.u0, r.v0)), fixed(place.at(r.u1, r.v0)), fixed(place.at(r.u1, r.v1)),
                fixed(place.at(r.u0, r.v1))},
               grey);
}

// A rectangle whose corners are quarter circles of `radius` (clamped to the
// shorter half side).
void fill_rounded(cv::Mat& img, const Place& place, const Rect& r, double radius, double grey) {
  if (!(r.u1 > r.u0 && r.v1 > r.v0)) return;
  const double rad = std::clamp(radius, 0.0, std::min(r.width(), r.height()) / 2);
  constexpr int kArc = 8;  // segments a corner
  const std::array<std::array<double, 3>, 4> corners{{
      {r.u1 - rad, r.v0 + rad, -0.5 * std::numbers::pi},
      {r.u1 - rad, r.v1 - rad, 0},
      {r.u0 + rad, r.v1 - rad, 0.5 * std::numbers::pi},
      {r.u0 + rad, r.v0 + rad, std::numbers::pi},
  }};
  std::vector<cv::Point> points;
  points.reserve(4 * (kArc + 1));
  for (const auto& [mu, mv, start] : corners) {
    for (int k = 0; k <= kArc; ++k) {
      const double a = start + 0.5 * std::numbers::pi * k / kArc;
      points.push_back(fixed(place.at(mu + rad * std::cos(a), mv + rad * std::sin(a))));
    }
  }
  fill_polygon(img, points, grey);
}

void fill_circle(cv::Mat& img, const Place& place, double u, double v, double radius, double grey) {
  if (!(radius > 0)) return;
  cv::circle(img, fixed(place.at(u, v)), static_cast<int>(std::lround(radius * (1 << kShift))), cv::Scalar(grey),
             cv::FILLED, cv::LINE_AA, kShift);
}

// Draws `patch` (masked by `mask`: 255 opaque) onto the canvas, its centre
// at `centre`, turned by `angle`: for what cv cannot draw turned (text).
void paste(cv::Mat& canvas, const cv::Mat& patch, const cv::Mat& mask, cv::Point2d centre, double angle) {
  const double ca = std::cos(angle), sa = std::sin(angle);
  const double hw = patch.cols / 2.0, hh = patch.rows / 2.0;
  double x0 = 1e300, y0 = 1e300, x1 = -1e300, y1 = -1e300;
  for (const double u : {-hw, hw}) {
    for (const double v : {-hh, hh}) {
      x0 = std::min(x0, centre.x + ca * u - sa * v), x1 = std::max(x1, centre.x + ca * u - sa * v);
      y0 = std::min(y0, centre.y + sa * u + ca * v), y1 = std::max(y1, centre.y + sa * u + ca * v);
    }
  }
  const cv::Rect roi = cv::Rect(cv::Point(static_cast<int>(std::floor(x0)) - 1, static_cast<int>(std::floor(y0)) - 1),
                                cv::Point(static_cast<int>(std::ceil(x1)) + 2, static_cast<int>(std::ceil(y1)) + 2)) &
                       cv::Rect(0, 0, canvas.cols, canvas.rows);
  if (roi.empty()) return;
  // Patch pixel centres (x + 0.5) map to canvas pixel centres.
  const double tx = centre.x - roi.x - 0.5, ty = centre.y - roi.y - 0.5;
  const cv::Matx23d m(ca, -sa, tx - ca * (hw - 0.5) + sa * (hh - 0.5), sa, ca, ty - sa * (hw - 0.5) - ca * (hh - 0.5));
  cv::Mat warped, alpha;
  cv::warpAffine(patch, warped, m, roi.size(), cv::INTER_LINEAR, cv::BORDER_CONSTANT, cv::Scalar(0));
  cv::warpAffine(mask, alpha, m, roi.size(), cv::INTER_LINEAR, cv::BORDER_CONSTANT, cv::Scalar(0));
  cv::Mat target = canvas(roi);
  for (int y = 0; y < roi.height; ++y) {
    auto* dst = target.ptr<std::uint8_t>(y);
    const auto* src = warped.ptr<std::uint8_t>(y);
    const auto* a = alpha.ptr<std::uint8_t>(y);
    for (int x = 0; x < roi.width; ++x) {
      dst[x] = static_cast<std::uint8_t>((dst[x] * (255 - a[x]) + src[x] * a[x] + 127) / 255);
    }
  }
}

struct Pen {
  cv::Mat& canvas;
  Random& rng;
  double unit;  // pixels of a 480-line image
  double wall;  // the bare wall's grey

  // From lo to hi with every scale equally likely: as many small sizes as large.
  double log_uniform(double lo, double hi) { return std::exp(rng.uniform(std::log(lo), std::log(hi))); }
  bool chance(double p) { return rng.uniform() < p; }
  // Somewhere in the image, or a little beyond its edges.
  cv::Point2d anywhere(double beyond) {
    return {rng.uniform(-beyond, 1 + beyond) * canvas.cols, rng.uniform(-beyond, 1 + beyond) * canvas.rows};
  }
  // The image's centre, moved by up to `share` of its smaller side.
  cv::Point2d near_centre(double share) {
    const double s = share * std::min(canvas.cols, canvas.rows);
    return {canvas.cols / 2.0 + rng.uniform(-s, s), canvas.rows / 2.0 + rng.uniform(-s, s)};
  }
  // Half the side of a square about the image's centre that covers the image
  // however it is turned, with `slack` pixels to spare for moving it.
  [[nodiscard]] double covering_half(double slack) const { return std::hypot(canvas.cols, canvas.rows) / 2 + slack; }
};

// A grey `contrast` away from `grey`, lighter or darker at random, or the
// other way when that way leaves the 5..250 range.
double against(Pen& pen, double grey, double contrast) {
  const double darker = grey - contrast, lighter = grey + contrast;
  const bool dark = pen.chance(0.5);
  if (dark) return darker >= 5 ? darker : std::min(lighter, 250.0);
  return lighter <= 250 ? lighter : std::max(darker, 5.0);
}

// A wall of tiles in grout, the rows in line or offset by half a tile as
// bricks are, a few tiles of another colour among them.
void draw_tiles(Pen& pen) {
  const double w = pen.unit * pen.log_uniform(4, 80);
  const double h = pen.chance(0.5) ? w : std::max(3.0 * pen.unit, w * pen.rng.uniform(0.4, 2.5));
  const double grout = std::max(1.0, std::min(w, h) * pen.rng.uniform(0.04, 0.15));
  const double tile = pen.rng.uniform(40, 235);
  const double joint = against(pen, tile, pen.rng.uniform(25, 120));
  const double jitter = pen.rng.uniform(0, 12);
  const double odd_share = pen.chance(0.3) ? pen.rng.uniform(0.03, 0.3) : 0;
  const bool bond = pen.chance(0.3);
  const Place place{pen.near_centre(0.1), deg(pen.rng.uniform(-8, 8))};
  const double half = pen.covering_half(0.1 * std::min(pen.canvas.cols, pen.canvas.rows) + w + h);
  // Tile corners on a lattice with a random phase, so that the grout does
  // not always cross at the image's centre.
  const double phase_u = pen.rng.uniform(0, w), phase_v = pen.rng.uniform(0, h);
  fill_rect(pen.canvas, place, {-half, -half, half, half}, joint);
  const int cols = static_cast<int>(std::ceil(2 * half / w)) + 2, rows = static_cast<int>(std::ceil(2 * half / h)) + 1;
  for (int r = 0; r < rows; ++r) {
    const double v0 = -half - phase_v + r * h;
    const double shift = bond && r % 2 == 1 ? w / 2 : 0;
    for (int c = 0; c < cols; ++c) {
      const double u0 = -half - phase_u - shift + c * w;
      const double grey = pen.chance(odd_share) ? pen.rng.uniform(10, 245) : tile + pen.rng.uniform(-jitter, jitter);
      fill_rect(pen.canvas, place, Rect{u0, v0, u0 + w, v0 + h}.inset(grout / 2), grey);
    }
  }
}

// Keyboard layouts' letter rows, to print on the keys.
constexpr std::array<std::array<std::string_view, 4>, 3> kLayouts{{
    {"1234567890-=", "QWERTYUIOP[]", "ASDFGHJKL;'", "ZXCVBNM,./"},
    {"1234567890SZ", "QWERTZUIOPU+", "ASDFGHJKLOA", "YXCVBNM,.-"},
    {"1234567890)=", "AZERTYUIOP^$", "QSDFGHJKLM%", "WXCVBN,;:!"},
}};

// Rows of rounded keys with letters printed on them, light keys on a dark
// base or dark keys on a light one, with the wide keys of a real layout and
// sometimes a number pad.
void draw_keyboard(Pen& pen) {
  const double pitch = pen.unit * pen.log_uniform(12, 60);
  const double key = pitch * pen.rng.uniform(0.78, 0.92);
  const double round = key * pen.rng.uniform(0.05, 0.2);
  const double top_inset = key * pen.rng.uniform(0.04, 0.14);  // the cap's top face inside its sloped sides
  const bool light_keys = pen.chance(0.5);
  const double base = light_keys ? pen.rng.uniform(15, 80) : pen.rng.uniform(150, 235);
  const double cap = light_keys ? pen.rng.uniform(165, 245) : pen.rng.uniform(12, 75);
  const double side = cap * pen.rng.uniform(0.8, 0.95);
  const double ink = light_keys ? pen.rng.uniform(5, 90) : pen.rng.uniform(170, 250);
  const bool function_row = pen.chance(0.6), number_pad = pen.chance(0.4);
  const auto& layout = kLayouts[static_cast<std::size_t>(pen.rng.integer(0, static_cast<int>(kLayouts.size()) - 1))];
  const int font = pen.chance(0.5) ? cv::FONT_HERSHEY_SIMPLEX : cv::FONT_HERSHEY_DUPLEX;
  const double letter_height = key * pen.rng.uniform(0.22, 0.42);
  const bool centred = pen.chance(0.5);

  // Key rows in units of the pitch: (x, width) of each key, the Mac and PC
  // wide keys at their usual widths.
  struct Key {
    double x, y, w, h;
    std::string label;
  };
  std::vector<Key> keys;
  double y = 0;
  if (function_row) {
    keys.push_back({0, 0, 1, 1, "Esc"});
    for (int k = 0; k < 12; ++k) {
      const int group = k / 4;  // the F keys in fours, half a key apart
      keys.push_back({2 + k + 0.5 * group, 0, 1, 1, "F" + std::to_string(k + 1)});
    }
    y = 1.5;
  }
  const auto row_of = [&](std::string_view letters, double x, double row_y) {
    for (const char c : letters) {
      keys.push_back({x, row_y, 1, 1, std::string(1, c)});
      x += 1;
    }
    return x;
  };
  double x = row_of(layout[0], 0, y);
  keys.push_back({x, y, 15 - x, 1, "Back"});
  keys.push_back({0, y + 1, 1.5, 1, "Tab"});
  x = row_of(layout[1], 1.5, y + 1);
  keys.push_back({x, y + 1, 15 - x, 1, "\\"});
  keys.push_back({0, y + 2, 1.75, 1, "Caps"});
  x = row_of(layout[2], 1.75, y + 2);
  keys.push_back({x, y + 2, 15 - x, 1, "Enter"});
  keys.push_back({0, y + 3, 2.25, 1, "Shift"});
  x = row_of(layout[3], 2.25, y + 3);
  keys.push_back({x, y + 3, 15 - x, 1, "Shift"});
  const std::array<std::pair<double, std::string_view>, 8> bottom{{{1.25, "Ctrl"},
                                                                   {1.25, "Fn"},
                                                                   {1.25, "Alt"},
                                                                   {6.25, ""},
                                                                   {1.25, "Alt"},
                                                                   {1.25, ""},
                                                                   {1.25, "Menu"},
                                                                   {1.25, "Ctrl"}}};
  x = 0;
  for (const auto& [width, label] : bottom) {
    keys.push_back({x, y + 4, width, 1, std::string(label)});
    x += width;
  }
  double columns = 15;
  if (number_pad) {
    static constexpr std::string_view kPad = "789-456+123*0.=/";
    for (int k = 0; k < 16; ++k) {
      const int row = k / 4, col = k % 4;
      keys.push_back({15.5 + col, y + 1 + row, 1, 1, std::string(1, kPad[static_cast<std::size_t>(k)])});
    }
    keys.push_back({15.5, y, 1, 1, "Num"});
    columns = 19.5;
  }
  const double rows = y + 5;

  const double margin = pitch * pen.rng.uniform(0.3, 1.0);
  const int width = static_cast<int>(std::ceil(columns * pitch + 2 * margin));
  const int height = static_cast<int>(std::ceil(rows * pitch + 2 * margin));
  cv::Mat patch(height, width, CV_8U, cv::Scalar(0)), mask(height, width, CV_8U, cv::Scalar(0));
  const Place flat({0, 0}, 0);
  const Rect plate{0, 0, static_cast<double>(width), static_cast<double>(height)};
  fill_rounded(patch, flat, plate, margin, base);
  fill_rounded(mask, flat, plate, margin, 255);
  const double gap = (pitch - key) / 2;
  for (const Key& k : keys) {
    const Rect outline{margin + k.x * pitch + gap, margin + k.y * pitch + gap, margin + (k.x + k.w) * pitch - gap,
                       margin + (k.y + k.h) * pitch - gap};
    fill_rounded(patch, flat, outline, round, side);
    const Rect top = outline.inset(top_inset);
    fill_rounded(patch, flat, top, round * 0.8, cap);
    if (k.label.empty()) continue;
    // Long names in a smaller size, as printed on wide keys.
    const double size = k.label.size() > 1 ? 0.6 * letter_height : letter_height;
    int baseline = 0;
    const cv::Size unit_size = cv::getTextSize("H", font, 1.0, 1, &baseline);
    const double scale = size / unit_size.height;
    const int thickness = std::max(1, static_cast<int>(std::lround(size / 9)));
    const cv::Size text = cv::getTextSize(k.label, font, scale, thickness, &baseline);
    const double pad = top.width() * 0.12;
    const double tx = centred ? top.mid_u() - text.width / 2.0 : top.u0 + pad;
    const double ty = centred ? top.mid_v() + text.height / 2.0 : top.v0 + pad + text.height;
    cv::putText(patch, k.label, cv::Point(static_cast<int>(tx), static_cast<int>(ty)), font, scale, cv::Scalar(ink),
                thickness, cv::LINE_AA);
  }
  paste(pen.canvas, patch, mask, pen.near_centre(0.3), deg(pen.rng.uniform(-20, 20)));
}

// A calibration board: a whole checkerboard on white paper, at any turn.
void draw_checkerboard(Pen& pen) {
  const int cols = pen.rng.integer(4, 12), rows = pen.rng.integer(3, 9);
  const double square = pen.unit * pen.log_uniform(6, 60);
  const double margin = square * pen.rng.uniform(0.4, 2.0);
  const double paper = pen.rng.uniform(170, 245), ink = pen.rng.uniform(8, 65);
  const int parity = pen.rng.integer(0, 1);
  const Place place{pen.near_centre(0.25), deg(pen.rng.uniform(0, 360))};
  const double hu = cols * square / 2, hv = rows * square / 2;
  fill_rect(pen.canvas, place, {-hu - margin, -hv - margin, hu + margin, hv + margin}, paper);
  for (int r = 0; r < rows; ++r) {
    for (int c = 0; c < cols; ++c) {
      if ((r + c) % 2 != parity) continue;
      fill_rect(pen.canvas, place, {-hu + c * square, -hv + r * square, -hu + (c + 1) * square, -hv + (r + 1) * square},
                ink);
    }
  }
}

// A building's facade: a grid of windows, each a light frame around dark
// panes that mullions divide in two (side by side or one above the other)
// or in four, sometimes with a sill below and bands between the storeys.
void draw_windows(Pen& pen) {
  const double ww = pen.unit * pen.log_uniform(10, 90);
  const double wh = ww * pen.rng.uniform(1.0, 1.8);
  const double pitch_u = ww * pen.rng.uniform(1.3, 2.3), pitch_v = wh * pen.rng.uniform(1.25, 2.0);
  const double facade = pen.rng.uniform(60, 230);
  const double frame = pen.rng.uniform(190, 250);
  const double band = std::max(1.0, ww * pen.rng.uniform(0.05, 0.12));
  const double mullion = std::max(1.0, band * pen.rng.uniform(0.5, 1.0));
  const double pane = pen.rng.uniform(15, 90), reflection = pen.rng.uniform(0, 30);
  const int division = pen.rng.integer(0, 2);  // 0: side by side, 1: one above the other, 2: four
  const bool sills = pen.chance(0.5);
  const double sill = std::max(1.0, band * pen.rng.uniform(0.6, 1.2));
  const bool storey_bands = pen.chance(0.3);
  const double storey_grey = against(pen, facade, pen.rng.uniform(15, 60));
  const Place place{pen.near_centre(0.1), deg(pen.rng.uniform(-5, 5))};
  const double half = pen.covering_half(0.1 * std::min(pen.canvas.cols, pen.canvas.rows) + pitch_u + pitch_v);
  const double phase_u = pen.rng.uniform(0, pitch_u), phase_v = pen.rng.uniform(0, pitch_v);
  fill_rect(pen.canvas, place, {-half, -half, half, half}, facade);
  const int cols = static_cast<int>(std::ceil(2 * half / pitch_u)) + 1;
  const int rows = static_cast<int>(std::ceil(2 * half / pitch_v)) + 1;
  for (int r = 0; r < rows; ++r) {
    const double v0 = -half - phase_v + r * pitch_v;
    if (storey_bands) {
      const double bv = v0 + wh + (pitch_v - wh) / 2;
      fill_rect(pen.canvas, place, {-half, bv - band, half, bv + band}, storey_grey);
    }
    for (int c = 0; c < cols; ++c) {
      const double u0 = -half - phase_u + c * pitch_u;
      const Rect window{u0, v0, u0 + ww, v0 + wh};
      fill_rect(pen.canvas, place, window, frame);
      if (sills) fill_rect(pen.canvas, place, {u0 - band, v0 + wh, u0 + ww + band, v0 + wh + sill}, frame);
      // The panes as one dark rectangle, each its own reflection of the sky,
      // then the mullions over it.
      const Rect glass = window.inset(band);
      const double mu = glass.mid_u(), mv = glass.mid_v();
      // Cut at the middle across (split_u) and down (split_v).
      const bool split_u = division != 1, split_v = division != 0;
      for (const double u : {glass.u0, mu}) {
        for (const double v : {glass.v0, mv}) {
          if ((u > glass.u0 && !split_u) || (v > glass.v0 && !split_v)) continue;
          const Rect one{u, v, split_u && u == glass.u0 ? mu : glass.u1, split_v && v == glass.v0 ? mv : glass.v1};
          fill_rect(pen.canvas, place, one, std::clamp(pane + pen.rng.uniform(-reflection, reflection), 0.0, 255.0));
        }
      }
      if (split_u) fill_rect(pen.canvas, place, {mu - mullion / 2, glass.v0, mu + mullion / 2, glass.v1}, frame);
      if (split_v) fill_rect(pen.canvas, place, {glass.u0, mv - mullion / 2, glass.u1, mv + mullion / 2}, frame);
    }
  }
}

// Words of random letters, some capitalised, a few numbers.
std::string word(Pen& pen) {
  static constexpr std::string_view kLower = "etaoinshrdlucmfwypvbgkqjxz";
  static constexpr std::string_view kUpper = "ETAOINSHRDLUCMFWYPVBGKQJXZ";
  static constexpr std::string_view kDigits = "0123456789";
  // Letter frequencies fall off roughly so: the first letters most often.
  const auto letter = [&](std::string_view set) {
    const double x = pen.rng.uniform();
    return set[std::min(set.size() - 1, static_cast<std::size_t>(x * x * static_cast<double>(set.size())))];
  };
  std::string w;
  if (pen.chance(0.06)) {
    const int n = pen.rng.integer(1, 4);
    for (int i = 0; i < n; ++i) w += kDigits[static_cast<std::size_t>(pen.rng.integer(0, 9))];
    return w;
  }
  const int n = pen.rng.integer(1, 10);
  for (int i = 0; i < n; ++i) w += i == 0 && pen.chance(0.15) ? letter(kUpper) : letter(kLower);
  if (pen.chance(0.1)) w += pen.chance(0.5) ? "," : ".";
  return w;
}

// A printed page: paragraphs of text lines in one or two columns, a heading
// now and then in a larger size.
void draw_text(Pen& pen) {
  const double scale = std::min(pen.canvas.cols, pen.canvas.rows);
  const double page_w = scale * pen.rng.uniform(0.6, 1.8);
  const double page_h = page_w * pen.rng.uniform(1.2, 1.5);
  const double paper = pen.rng.uniform(185, 248), ink = pen.rng.uniform(5, 70);
  static constexpr std::array<int, 5> kFonts{cv::FONT_HERSHEY_SIMPLEX, cv::FONT_HERSHEY_DUPLEX,
                                             cv::FONT_HERSHEY_COMPLEX, cv::FONT_HERSHEY_TRIPLEX,
                                             cv::FONT_HERSHEY_PLAIN};
  const int face = kFonts[static_cast<std::size_t>(pen.rng.integer(0, static_cast<int>(kFonts.size()) - 1))];
  const int font = face | (pen.chance(0.15) ? cv::FONT_ITALIC : 0);
  const double letter_height = pen.unit * pen.log_uniform(4, 28);  // a capital's
  const double spacing = letter_height * pen.rng.uniform(1.6, 2.4);
  const int thickness = std::max(1, static_cast<int>(std::lround(letter_height / pen.rng.uniform(9, 16))));
  const int columns = pen.chance(0.3) ? 2 : 1;
  const double margin = page_w * pen.rng.uniform(0.04, 0.12);
  const double gutter = page_w * 0.05;
  const double column_w = (page_w - 2 * margin - (columns - 1) * gutter) / columns;

  const auto width = static_cast<int>(std::ceil(page_w)), height = static_cast<int>(std::ceil(page_h));
  cv::Mat patch(height, width, CV_8U, cv::Scalar(paper)), mask(height, width, CV_8U, cv::Scalar(255));
  int baseline = 0;
  const double unit_height = cv::getTextSize("H", font, 1.0, 1, &baseline).height;
  for (int col = 0; col < columns; ++col) {
    const double x0 = margin + col * (column_w + gutter);
    double y = margin;
    bool paragraph_start = true;
    while (true) {
      const bool heading = paragraph_start && pen.chance(0.15);
      const double size = heading ? letter_height * pen.rng.uniform(1.4, 2.2) : letter_height;
      const double line_scale = size / unit_height;
      const int line_thickness = heading ? thickness + 1 : thickness;
      y += heading ? size * 1.8 : spacing;
      if (y > page_h - margin) break;
      // Words until the column is full; a paragraph's last line ends early.
      const bool last_line = heading || pen.chance(0.15);
      const double fill = last_line ? pen.rng.uniform(0.2, 0.9) : 1.0;
      std::string line = paragraph_start && !heading ? "    " : "";
      while (true) {
        const std::string next = line.empty() || line.back() == ' ' ? line + word(pen) : line + " " + word(pen);
        if (cv::getTextSize(next, font, line_scale, line_thickness, &baseline).width > fill * column_w) break;
        line = next;
      }
      cv::putText(patch, line, cv::Point(static_cast<int>(x0), static_cast<int>(y)), font, line_scale, cv::Scalar(ink),
                  line_thickness, cv::LINE_AA);
      paragraph_start = last_line;
      if (last_line && !heading) y += spacing * pen.rng.uniform(0, 0.8);
    }
  }
  paste(pen.canvas, patch, mask, pen.near_centre(0.3), deg(pen.rng.uniform(-12, 12)));
}

// Socket outlets and light switches on a wall, without a marker: square
// plates with rounded corners, light or dark, each a one-piece plate or a
// frame (of one, two or three gangs) around inserts, casting a shadow. A
// socket is a round recess with two pin holes (and earthing clips); a
// switch a rocker, sometimes split in two, in a dark gap.
void draw_outlets(Pen& pen) {
  const int count = pen.rng.integer(2, 6);
  for (int i = 0; i < count; ++i) {
    const double size = pen.unit * pen.log_uniform(30, 170);  // one gang's side
    const bool light = pen.chance(0.65);
    const double plastic = light ? pen.rng.uniform(185, 245) : pen.rng.uniform(20, 80);
    const double corner = size * pen.rng.uniform(0.04, 0.18);
    const int gangs = pen.chance(0.7) ? 1 : pen.rng.integer(2, 3);
    const bool framed = gangs > 1 || pen.chance(0.5);
    const bool vertical = pen.chance(0.3);  // the gangs one above the other
    const double tilt = deg(pen.rng.uniform(-8, 8));
    const Place place{pen.anywhere(0.05), tilt};
    const double hu = vertical ? size / 2 : size * gangs / 2, hv = vertical ? size * gangs / 2 : size / 2;
    const Rect outer{-hu, -hv, hu, hv};
    // The shadow on the wall, down and to one side of the plate.
    const double sdu = size * pen.rng.uniform(-0.05, 0.05), sdv = size * pen.rng.uniform(0, 0.06);
    fill_rounded(pen.canvas, place, {outer.u0 + sdu, outer.v0 + sdv, outer.u1 + sdu, outer.v1 + sdv}, corner,
                 pen.wall * pen.rng.uniform(0.55, 0.85));
    fill_rounded(pen.canvas, place, outer, corner, plastic);
    const double opening = framed ? size * pen.rng.uniform(0.62, 0.74) : size * pen.rng.uniform(0.6, 0.72);
    const double gap_grey = plastic * pen.rng.uniform(0.3, 0.6);
    const double gap = std::max(1.0, size * pen.rng.uniform(0.006, 0.015));
    for (int g = 0; g < gangs; ++g) {
      const double along = size * (g + 0.5);
      const Place gang(vertical ? place.at(0, -hv + along) : place.at(-hu + along, 0), tilt);
      const Rect insert{-opening / 2, -opening / 2, opening / 2, opening / 2};
      double face = plastic;
      if (framed) {
        face = std::clamp(plastic + pen.rng.uniform(-15, 15), 0.0, 255.0);
        fill_rounded(pen.canvas, gang, insert, corner * 0.5, gap_grey);
        fill_rounded(pen.canvas, gang, insert.inset(gap), corner * 0.5, face);
      }
      if (pen.chance(0.6)) {
        const double recess = opening * pen.rng.uniform(0.72, 0.92) / 2;  // radius
        const double rim = recess * pen.rng.uniform(0.04, 0.1);
        const double floor = face * pen.rng.uniform(0.5, 0.85);
        fill_circle(pen.canvas, gang, 0, 0, recess, face * pen.rng.uniform(0.4, 0.7));
        fill_circle(pen.canvas, gang, 0, 0, recess - rim, floor);
        if (pen.chance(0.5)) {
          const double clip_w = recess * 0.4, clip_h = recess * 0.14, metal = pen.rng.uniform(140, 220);
          fill_rect(pen.canvas, gang, {-clip_w / 2, -recess + rim, clip_w / 2, -recess + rim + clip_h}, metal);
          fill_rect(pen.canvas, gang, {-clip_w / 2, recess - rim - clip_h, clip_w / 2, recess - rim}, metal);
        }
        const double pins = recess * pen.rng.uniform(0.44, 0.52), hole = recess * pen.rng.uniform(0.1, 0.14);
        const double dark = pen.rng.uniform(3, 35);
        fill_circle(pen.canvas, gang, -pins, 0, hole, dark);
        fill_circle(pen.canvas, gang, pins, 0, hole, dark);
      } else {
        const double rw = opening * pen.rng.uniform(0.55, 0.9), rh = opening * pen.rng.uniform(0.55, 0.92);
        const double rocker = std::clamp(face + pen.rng.uniform(-25, 25), 0.0, 255.0);
        const Rect rect{-rw / 2, -rh / 2, rw / 2, rh / 2};
        fill_rounded(pen.canvas, gang, rect, corner * 0.3, gap_grey);
        if (pen.chance(0.25)) {
          fill_rounded(pen.canvas, gang, {rect.u0 + gap, rect.v0 + gap, -gap / 2, rect.v1 - gap}, corner * 0.2, rocker);
          fill_rounded(pen.canvas, gang, {gap / 2, rect.v0 + gap, rect.u1 - gap, rect.v1 - gap}, corner * 0.2, rocker);
        } else {
          fill_rounded(pen.canvas, gang, rect.inset(gap), corner * 0.2, rocker);
        }
        if (pen.chance(0.4)) {  // the lamp or the mark of "on"
          fill_rect(pen.canvas, gang, {-rw * 0.03, -rh * 0.35, rw * 0.03, -rh * 0.2}, gap_grey);
        }
      }
    }
  }
}

void draw_texture(cv::Mat& img, Random& rng, double wall, Background kind) {
  cv::Mat canvas(img.size(), CV_8U, cv::Scalar(wall));
  Pen pen{canvas, rng, std::min(img.cols, img.rows) / 480.0, wall};
  switch (kind) {
    case Background::shapes: break;  // not a texture: draw_shapes
    case Background::tiles: draw_tiles(pen); break;
    case Background::keyboard: draw_keyboard(pen); break;
    case Background::checkerboard: draw_checkerboard(pen); break;
    case Background::windows: draw_windows(pen); break;
    case Background::text: draw_text(pen); break;
    case Background::outlets: draw_outlets(pen); break;
  }
  // The gradient in `img` lights the canvas: the wall comes out as the
  // gradient itself.
  for (int y = 0; y < img.rows; ++y) {
    auto* row = img.ptr<std::uint8_t>(y);
    const auto* grey = canvas.ptr<std::uint8_t>(y);
    for (int x = 0; x < img.cols; ++x) row[x] = cv::saturate_cast<std::uint8_t>(grey[x] * (row[x] / wall));
  }
}

}  // namespace

// The clutter, or the flat background_grey (by default mid grey, lighter
// than the ink so that a cut hole still shows the frame8 line's inner edge).
// Float, as the converted 8-bit image of a whole grey level always was.
cv::Mat make_background(int width, int height, const Scene& scene) {
  if (!scene.clutter) return cv::Mat(height, width, CV_32F, cv::Scalar(scene.background_grey));
  cv::Mat img(height, width, CV_8U);
  Random rng(scene.seed);
  // A smooth illumination gradient under everything.
  const double g0 = rng.uniform(70, 190), gx = rng.uniform(-60, 60), gy = rng.uniform(-60, 60);
  for (int y = 0; y < height; ++y) {
    auto* row = img.ptr<std::uint8_t>(y);
    const double base = g0 + gy * (static_cast<double>(y) / height - 0.5);
    for (int x = 0; x < width; ++x) {
      row[x] = cv::saturate_cast<std::uint8_t>(base + gx * (static_cast<double>(x) / width - 0.5));
    }
  }
  if (scene.background == Background::shapes) {
    draw_shapes(img, rng);
  } else {
    draw_texture(img, rng, g0, scene.background);
  }
  return img;
}

}  // namespace render
}  // namespace markerd::detector
