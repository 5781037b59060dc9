#pragma once
// What the renderer's tests share (test_render.cpp, test_render_surface.cpp):
// a plain camera, an independent projection of marker points, pixel reads
// and the ink and paper levels.

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>
#include <string>

#include "markerd/detector/render.hpp"

namespace markerd::detector::render_test {

inline CameraModel pinhole_camera() {
  CameraModel c;
  c.width = 640;
  c.height = 480;
  c.fx = 500;
  c.fy = 500;
  c.cx = 320;
  c.cy = 240;
  return c;
}

// Independent of the renderer's own projection: OpenCV's model is checked
// against it separately (ProjectCornersMatchOpenCv).
inline Point2 project_uv(const CameraModel& cam, const Scene& scene, double u, double v) {
  const Eigen::Vector3d p = scene.pose.rotation * Eigen::Vector3d(u * scene.marker_size_m, v * scene.marker_size_m, 0) +
                            scene.pose.translation;
  const Point2 n{p.x() / p.z(), p.y() / p.z()};
  if (scene.distort) return cam.normalized_to_pixel(n);
  return {cam.fx * n.x + cam.cx, cam.fy * n.y + cam.cy};
}

inline std::uint8_t pixel_at(const GreyImage& img, Point2 p) {
  const int x = static_cast<int>(std::lround(p.x)), y = static_cast<int>(std::lround(p.y));
  EXPECT_TRUE(x >= 0 && y >= 0 && x < img.width() && y < img.height()) << p.x << "," << p.y;
  return img.at(std::clamp(x, 0, img.width() - 1), std::clamp(y, 0, img.height() - 1));
}

inline cv::Mat as_mat(const GreyImage& img) {
  return cv::Mat(img.height(), img.width(), CV_8U, const_cast<std::uint8_t*>(img.data())).clone();
}

inline void maybe_dump(const GreyImage& img, const std::string& name) {
  if (const char* dir = std::getenv("MARKERD_TEST_DUMP_DIR")) {
    cv::imwrite((std::filesystem::path(dir) / (name + ".png")).string(), as_mat(img));
  }
}

inline bool same_bytes(const GreyImage& a, const GreyImage& b) {
  return a.width() == b.width() && a.height() == b.height() &&
         std::equal(a.data(), a.data() + static_cast<std::size_t>(a.width()) * a.height(), b.data());
}

inline int count_different(const GreyImage& a, const GreyImage& b) {
  int n = 0;
  for (int i = 0; i < a.width() * a.height(); ++i) n += a.data()[i] != b.data()[i] ? 1 : 0;
  return n;
}

// Ink 0.05 and paper 0.88 at exposure 1, rounded: the levels of a pixel that
// lies wholly inside one cell.
inline constexpr int kWhite = 224;  // 0.88 * 255 = 224.4
inline constexpr int kBlack = 13;   // 0.05 * 255 = 12.75

}  // namespace markerd::detector::render_test
