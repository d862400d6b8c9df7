#include "gen/render/renderer.h"

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <iostream>
#include <stdexcept>
#include <string>
#include <utility>
#include <vector>

#include <gtest/gtest.h>
#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

namespace stackgen {
namespace {

// an axis-aligned box centred at the origin, one normal per face (24 vertices)
TriangleMesh MakeBox(const Eigen::Vector3f& size_mm) {
  TriangleMesh mesh;
  const Eigen::Vector3f half = size_mm / 2;
  for (int axis = 0; axis < 3; ++axis) {
    for (const float sign : {-1.f, 1.f}) {
      // face perpendicular to `axis`, corners counter-clockwise seen from outside
      Eigen::Vector3f normal = Eigen::Vector3f::Zero();
      normal[axis] = sign;
      const int u_axis = (axis + 1) % 3;
      const int v_axis = (axis + 2) % 3;
      const uint32_t first = static_cast<uint32_t>(mesh.positions_mm.size());
      for (const auto& [su, sv] : {std::pair{-1.f, -1.f}, {1.f, -1.f}, {1.f, 1.f}, {-1.f, 1.f}}) {
        Eigen::Vector3f p;
        p[axis] = sign * half[axis];
        p[u_axis] = su * half[u_axis];
        p[v_axis] = sv * half[v_axis];
        mesh.positions_mm.push_back(p);
        mesh.normals.push_back(normal);
      }
      if (sign > 0) {
        mesh.triangles.push_back({first, first + 1, first + 2});
        mesh.triangles.push_back({first, first + 2, first + 3});
      } else {
        mesh.triangles.push_back({first, first + 2, first + 1});
        mesh.triangles.push_back({first, first + 3, first + 2});
      }
    }
  }
  return mesh;
}

// a square in the object's z = 0 plane, normal +z
TriangleMesh MakeSquare(float size_mm) {
  TriangleMesh mesh;
  const float h = size_mm / 2;
  mesh.positions_mm = {{-h, -h, 0}, {h, -h, 0}, {h, h, 0}, {-h, h, 0}};
  mesh.normals.assign(4, Eigen::Vector3f::UnitZ());
  mesh.triangles = {{0, 1, 2}, {0, 2, 3}};
  return mesh;
}

Eigen::Isometry3d Translation(double x, double y, double z) {
  return Eigen::Isometry3d(Eigen::Translation3d(x, y, z));
}

// a camera at world (0, 0, height) looking straight down at the z = 0 plane
CameraModel CameraLookingDown(double height_mm) {
  CameraModel camera;
  camera.world_from_camera = Translation(0, 0, height_mm);
  camera.world_from_camera.linear() = Eigen::Vector3d(1, -1, -1).asDiagonal();
  return camera;
}

// pixel (u, v) of a world point by the pinhole formula
Eigen::Vector2d Project(const CameraModel& camera, const Eigen::Vector3d& point_world) {
  const Eigen::Vector3d p = camera.world_from_camera.inverse() * point_world;
  return {camera.fx * p.x() / p.z() + camera.cx, camera.fy * p.y() / p.z() + camera.cy};
}

// hue in degrees [0, 360) of a display RGB colour
double Hue(double r, double g, double b) {
  const double max = std::max({r, g, b});
  const double min = std::min({r, g, b});
  if (max - min <= 0) return 0;
  double hue = 0;
  if (max == r) {
    hue = 60 * std::fmod((g - b) / (max - min) + 6, 6.0);
  } else if (max == g) {
    hue = 60 * ((b - r) / (max - min) + 2);
  } else {
    hue = 60 * ((r - g) / (max - min) + 4);
  }
  return hue;
}

double HueDistance(double a, double b) {
  const double d = std::fabs(a - b);
  return std::min(d, 360 - d);
}

std::vector<Light> FrontLights() {
  Light key;
  key.direction_world = Eigen::Vector3f(0.3f, 0.4f, -1.f).normalized();
  return {key};
}

// every pixel with instance id k has the colour of object k, id 0 the background; each object
// lies where it was drawn
TEST(RendererTest, InstanceMapAgreesWithColour) {
  Renderer renderer(640, 480);
  const int box = renderer.AddMesh(MakeBox({60, 60, 60}));
  const CameraModel camera = CameraLookingDown(1000);
  const Eigen::Vector3f background(0.5f, 0.5f, 0.5f);
  const std::vector<Eigen::Vector3f> colors = {
      {0.85f, 0.1f, 0.1f}, {0.1f, 0.8f, 0.15f}, {0.15f, 0.2f, 0.9f}, {0.85f, 0.8f, 0.1f}};
  const std::vector<Eigen::Vector3d> centers = {
      {-120, 60, 30}, {-20, -70, 30}, {60, 50, 30}, {150, -40, 30}};
  std::vector<DrawItem> items;
  for (size_t k = 0; k < colors.size(); ++k) {
    DrawItem item;
    item.mesh_id = box;
    item.world_from_object =
        Translation(centers[k].x(), centers[k].y(), centers[k].z()) *
        Eigen::AngleAxisd(0.4 + 0.3 * k, Eigen::Vector3d(1, 2, 3).normalized());
    item.instance_id = static_cast<uint16_t>(k + 1);
    item.material.color = colors[k];
    item.material.specular = 0.3f;
    items.push_back(item);
  }

  const RenderResult result = renderer.Render(camera, FrontLights(), background, items);
  ASSERT_EQ(result.color.type(), CV_8UC3);
  ASSERT_EQ(result.instance.type(), CV_16UC1);
  ASSERT_EQ(result.color.size(), cv::Size(640, 480));

  // colour of every pixel against its id
  std::vector<int> pixel_counts(colors.size() + 1, 0);
  for (int v = 0; v < result.color.rows; ++v) {
    for (int u = 0; u < result.color.cols; ++u) {
      const int id = result.instance.at<uint16_t>(v, u);
      const cv::Vec3b rgb = result.color.at<cv::Vec3b>(v, u);
      ASSERT_LE(id, static_cast<int>(colors.size())) << "pixel " << u << "," << v;
      ++pixel_counts[id];
      if (id == 0) {
        for (int c = 0; c < 3; ++c) {
          ASSERT_NEAR(rgb[c], background[c] * 255, 1) << "background pixel " << u << "," << v;
        }
        continue;
      }
      const Eigen::Vector3f& material = colors[id - 1];
      const double hue = Hue(rgb[0], rgb[1], rgb[2]);
      const double expected = Hue(material.x(), material.y(), material.z());
      ASSERT_LT(HueDistance(hue, expected), 15) << "object " << id << " pixel " << u << "," << v;
    }
  }

  // each object covers a decent area around its projected centre
  for (size_t k = 0; k < centers.size(); ++k) {
    EXPECT_GT(pixel_counts[k + 1], 1500) << "object " << k + 1;
    const Eigen::Vector2d uv = Project(camera, centers[k]);
    EXPECT_EQ(result.instance.at<uint16_t>(static_cast<int>(std::lround(uv.y())),
                                           static_cast<int>(std::lround(uv.x()))),
              k + 1);
  }
}

// depth is the camera z of the surface to 0.05 mm; background depth is 0
TEST(RendererTest, DepthIsExact) {
  Renderer renderer(640, 480);
  const int square = renderer.AddMesh(MakeSquare(400));
  const CameraModel camera = CameraLookingDown(1000);
  DrawItem plane;
  plane.mesh_id = square;
  plane.instance_id = 1;

  // a plane facing the camera 1000 mm away
  RenderResult result = renderer.Render(camera, FrontLights(), {0, 0, 0}, {plane});
  ASSERT_EQ(result.depth_mm.type(), CV_32FC1);
  int plane_pixels = 0;
  for (int v = 0; v < result.depth_mm.rows; ++v) {
    for (int u = 0; u < result.depth_mm.cols; ++u) {
      const float depth = result.depth_mm.at<float>(v, u);
      if (result.instance.at<uint16_t>(v, u) == 1) {
        ++plane_pixels;
        ASSERT_NEAR(depth, 1000.0, 0.05) << "pixel " << u << "," << v;
      } else {
        ASSERT_EQ(depth, 0.f) << "pixel " << u << "," << v;
      }
    }
  }
  // 400 mm at 1000 mm with fx = fy = 800 covers 320 x 320 pixels
  EXPECT_NEAR(plane_pixels, 320 * 320, 2 * 320 + 1);

  // a plane tilted by 35 degrees: depth along each pixel's ray
  plane.world_from_object =
      Translation(20, -10, 0) *
      Eigen::AngleAxisd(35 * M_PI / 180, Eigen::Vector3d(1, 0.3, 0).normalized());
  renderer.Render(camera, FrontLights(), {0, 0, 0}, {plane}, &result);
  const Eigen::Isometry3d camera_from_object =
      camera.world_from_camera.inverse() * plane.world_from_object;
  const Eigen::Vector3d normal = camera_from_object.linear().col(2);
  const double offset = normal.dot(camera_from_object.translation());
  plane_pixels = 0;
  for (int v = 0; v < result.depth_mm.rows; ++v) {
    for (int u = 0; u < result.depth_mm.cols; ++u) {
      if (result.instance.at<uint16_t>(v, u) != 1) continue;
      ++plane_pixels;
      const Eigen::Vector3d ray((u - camera.cx) / camera.fx, (v - camera.cy) / camera.fy, 1);
      const double z = offset / normal.dot(ray);
      ASSERT_NEAR(result.depth_mm.at<float>(v, u), z, 0.05) << "pixel " << u << "," << v;
    }
  }
  EXPECT_GT(plane_pixels, 50000);
}

// a small box at a known point appears centred where the pinhole formula says (within 1 px),
// with +y of the camera down in the image
TEST(RendererTest, ProjectionIsExact) {
  CameraModel camera;
  camera.width = 640;
  camera.height = 480;
  camera.fx = 700;
  camera.fy = 650;
  camera.cx = 300.3;
  camera.cy = 250.8;
  camera.world_from_camera = Translation(30, -40, 900) *
                             Eigen::AngleAxisd(M_PI, Eigen::Vector3d::UnitX()) *
                             Eigen::AngleAxisd(0.2, Eigen::Vector3d(1, -1, 0.5).normalized());
  Renderer renderer(camera.width, camera.height);
  const int box = renderer.AddMesh(MakeBox({5, 5, 5}));

  // boxes at camera-frame points spread over the image
  const std::vector<Eigen::Vector3d> points_camera = {
      {0, 0, 900}, {200, 150, 950}, {-300, -250, 1000}, {250, -220, 850}, {-180, 200, 800}};
  std::vector<DrawItem> items;
  for (size_t k = 0; k < points_camera.size(); ++k) {
    DrawItem item;
    item.mesh_id = box;
    const Eigen::Vector3d point_world = camera.world_from_camera * points_camera[k];
    item.world_from_object = Translation(point_world.x(), point_world.y(), point_world.z());
    item.instance_id = static_cast<uint16_t>(k + 1);
    items.push_back(item);
  }
  const RenderResult result = renderer.Render(camera, FrontLights(), {0, 0, 0}, items);

  for (size_t k = 0; k < items.size(); ++k) {
    // centroid of the object's pixels
    const cv::Mat mask = result.instance == static_cast<int>(k + 1);
    const cv::Moments moments = cv::moments(mask, true);
    ASSERT_GT(moments.m00, 0) << "object " << k + 1 << " not drawn";
    const Eigen::Vector2d centroid(moments.m10 / moments.m00, moments.m01 / moments.m00);
    const Eigen::Vector2d expected = Project(camera, items[k].world_from_object.translation());
    EXPECT_NEAR(centroid.x(), expected.x(), 1.0) << "object " << k + 1;
    EXPECT_NEAR(centroid.y(), expected.y(), 1.0) << "object " << k + 1;
    // +y (camera) is down: below the principal point for y > 0
    EXPECT_EQ(centroid.y() > camera.cy, points_camera[k].y() > 0) << "object " << k + 1;
  }
}

// an object half covered by another has about twice as many silhouette pixels as visible ones;
// an unoccluded object's silhouette equals its visible pixels exactly
TEST(RendererTest, SilhouettesCoverOccludedPixels) {
  Renderer renderer(640, 480);
  const int box = renderer.AddMesh(MakeBox({60, 60, 20}));
  const int cover = renderer.AddMesh(MakeBox({100, 200, 20}));
  const int square = renderer.AddMesh(MakeSquare(1000));
  CameraModel camera;  // identity pose: world = camera frame

  DrawItem floor;  // a non-object behind everything
  floor.mesh_id = square;
  floor.world_from_object = Translation(0, 0, 1500);
  DrawItem half_hidden;
  half_hidden.mesh_id = box;
  half_hidden.world_from_object = Translation(0, 0, 1000);
  half_hidden.instance_id = 7;
  DrawItem occluder;  // right edge at x = 0.3 mm, 800 mm away: covers the left half
  occluder.mesh_id = cover;
  occluder.world_from_object = Translation(-49.7, 0, 800);
  occluder.instance_id = 9;
  const std::vector<DrawItem> items = {floor, half_hidden, occluder};

  const RenderResult result = renderer.Render(camera, FrontLights(), {0.2f, 0.2f, 0.2f}, items);
  const std::vector<cv::Mat> silhouettes = renderer.RenderSilhouettes(camera, items);
  ASSERT_EQ(silhouettes.size(), 2u);
  for (const cv::Mat& mask : silhouettes) {
    ASSERT_EQ(mask.type(), CV_8UC1);
    ASSERT_EQ(mask.size(), cv::Size(640, 480));
  }

  // half hidden: about 2x, and every visible pixel inside the silhouette
  const cv::Mat visible = result.instance == 7;
  const int visible_count = cv::countNonZero(visible);
  const int silhouette_count = cv::countNonZero(silhouettes[0]);
  ASSERT_GT(visible_count, 0);
  EXPECT_NEAR(static_cast<double>(silhouette_count) / visible_count, 2.0, 0.1);
  EXPECT_EQ(cv::countNonZero(visible & ~silhouettes[0]), 0);

  // the hidden object drawn alone covers exactly its silhouette
  const RenderResult alone =
      renderer.Render(camera, FrontLights(), {0.2f, 0.2f, 0.2f}, {half_hidden});
  EXPECT_EQ(cv::countNonZero((alone.instance == 7) != silhouettes[0]), 0);

  // unoccluded: exactly the visible pixels
  EXPECT_EQ(cv::countNonZero((result.instance == 9) != silhouettes[1]), 0);
  EXPECT_GT(cv::countNonZero(silhouettes[1]), 0);
}

// more objects than one silhouette pass holds (32): every unoccluded mask is exact
TEST(RendererTest, SilhouettesOfManyObjects) {
  Renderer renderer(640, 480);
  const int box = renderer.AddMesh(MakeBox({30, 30, 30}));
  const CameraModel camera = CameraLookingDown(1000);
  std::vector<DrawItem> items;
  for (int k = 0; k < 70; ++k) {
    DrawItem item;
    item.mesh_id = box;
    item.world_from_object = Translation(-330 + 60 * (k % 12), -230 + 75 * (k / 12), 0) *
                             Eigen::AngleAxisd(0.1 * k, Eigen::Vector3d(0, 1, 1).normalized());
    item.instance_id = static_cast<uint16_t>(1000 + k);
    items.push_back(item);
  }
  const RenderResult result = renderer.Render(camera, FrontLights(), {0, 0, 0}, items);
  const std::vector<cv::Mat> silhouettes = renderer.RenderSilhouettes(camera, items);
  ASSERT_EQ(silhouettes.size(), items.size());
  for (size_t k = 0; k < items.size(); ++k) {
    const cv::Mat visible = result.instance == items[k].instance_id;
    EXPECT_GT(cv::countNonZero(visible), 0) << "object " << k;
    EXPECT_EQ(cv::countNonZero(visible != silhouettes[k]), 0) << "object " << k;
  }
}

// closed meshes show their outside (back faces culled), open or inside-out meshes both sides
TEST(RendererTest, DrawsTheVisibleSideOfEveryMesh) {
  Renderer renderer(640, 480);
  const int box = renderer.AddMesh(MakeBox({100, 100, 100}));
  TriangleMesh inside_out = MakeBox({100, 100, 100});
  for (auto& triangle : inside_out.triangles) std::swap(triangle[1], triangle[2]);
  const int inverted_box = renderer.AddMesh(inside_out);
  const int square = renderer.AddMesh(MakeSquare(100));
  const CameraModel camera;  // identity pose: looking along +z

  // a closed box: its near face, 50 mm in front of its centre, 800 * 100 / 950 = 84.2 px wide
  const int face_px = 84;
  for (const int mesh_id : {box, inverted_box}) {
    DrawItem item;
    item.mesh_id = mesh_id;
    item.world_from_object = Translation(0, 0, 1000);
    item.instance_id = 1;
    const RenderResult result = renderer.Render(camera, FrontLights(), {0, 0, 0}, {item});
    EXPECT_NEAR(result.depth_mm.at<float>(240, 320), 950.0, 0.05) << "mesh " << mesh_id;
    EXPECT_EQ(cv::countNonZero(result.instance == 1), face_px * face_px) << "mesh " << mesh_id;
    EXPECT_EQ(cv::countNonZero(renderer.RenderSilhouettes(camera, {item})[0]), face_px * face_px);
  }

  // a square whose normal points away from the camera is still drawn (100 px wide)
  DrawItem item;
  item.mesh_id = square;
  item.world_from_object = Translation(0, 0, 800);
  item.instance_id = 2;
  const RenderResult result = renderer.Render(camera, FrontLights(), {0, 0, 0}, {item});
  EXPECT_NEAR(result.depth_mm.at<float>(240, 320), 800.0, 0.05);
  EXPECT_EQ(cv::countNonZero(result.instance == 2), 100 * 100);
}

// an unknown mesh_id is refused by Render and RenderSilhouettes; a bad mesh by AddMesh
TEST(RendererTest, BadInputThrows) {
  Renderer renderer(64, 48);
  const int box = renderer.AddMesh(MakeBox({10, 10, 10}));
  const CameraModel camera;
  for (const int mesh_id : {box + 1, -1, 42}) {
    DrawItem item;
    item.mesh_id = mesh_id;
    item.instance_id = 1;
    EXPECT_THROW(renderer.Render(camera, FrontLights(), {0, 0, 0}, {item}), std::runtime_error);
    EXPECT_THROW(renderer.RenderSilhouettes(camera, {item}), std::runtime_error);
  }
  TriangleMesh broken = MakeBox({10, 10, 10});
  broken.triangles.push_back({0, 1, 99});
  EXPECT_THROW(renderer.AddMesh(broken), std::runtime_error);
  EXPECT_THROW(renderer.AddMesh(TriangleMesh()), std::runtime_error);
  CameraModel bad_camera;
  bad_camera.near_mm = 0;
  EXPECT_THROW(renderer.Render(bad_camera, FrontLights(), {0, 0, 0}, {}), std::runtime_error);
  EXPECT_THROW(Renderer(0, 10), std::runtime_error);
}

// the framebuffer follows the camera size, and two renderers on one thread do not mix
TEST(RendererTest, ResizesAndSwitchesContexts) {
  Renderer first(640, 480);
  Renderer second(320, 240);
  const int box_first = first.AddMesh(MakeBox({50, 50, 50}));
  const int box_second = second.AddMesh(MakeSquare(2000));
  DrawItem item;
  item.instance_id = 3;
  item.world_from_object = Translation(0, 0, 500);

  CameraModel small;
  small.width = 160;
  small.height = 120;
  small.cx = 79.5;
  small.cy = 59.5;
  item.mesh_id = box_first;
  const RenderResult a = first.Render(small, FrontLights(), {0, 0, 0}, {item});
  item.mesh_id = box_second;
  const RenderResult b = second.Render(CameraModel(), FrontLights(), {0, 0, 0}, {item});
  EXPECT_EQ(a.color.size(), cv::Size(160, 120));
  EXPECT_EQ(b.color.size(), cv::Size(640, 480));
  // the square fills the whole image; the box only the centre
  EXPECT_EQ(cv::countNonZero(b.instance == 3), 640 * 480);
  EXPECT_LT(cv::countNonZero(a.instance == 3), 160 * 120 / 2);
  EXPECT_EQ(a.instance.at<uint16_t>(60, 80), 3);
}

// the description names the platform, the GL renderer and its version
TEST(RendererTest, DescribesTheContext) {
  const Renderer renderer(16, 16);
  const std::string description = renderer.Description();
  EXPECT_NE(description.find("EGL"), std::string::npos) << description;
  EXPECT_NE(description.find("GL_RENDERER"), std::string::npos) << description;
  EXPECT_NE(description.find("GL_VERSION"), std::string::npos) << description;
  std::cout << "renderer: " << description << "\n";
}

// a fixed scene matches the golden image within a tolerance (a diff image is written on
// failure); STACKGEN_UPDATE_GOLDEN=1 rewrites the golden image
TEST(RendererTest, MatchesGoldenImage) {
  Renderer renderer(320, 240);
  const int box = renderer.AddMesh(MakeBox({60, 40, 25}));
  const int square = renderer.AddMesh(MakeSquare(600));
  CameraModel camera = CameraLookingDown(700);
  camera.width = 320;
  camera.height = 240;
  camera.fx = camera.fy = 400;
  camera.cx = 159.5;
  camera.cy = 119.5;
  camera.world_from_camera =
      Eigen::AngleAxisd(0.35, Eigen::Vector3d::UnitX()) * camera.world_from_camera;
  std::vector<DrawItem> items;
  DrawItem floor;
  floor.mesh_id = square;
  floor.material.color = {0.6f, 0.55f, 0.45f};
  floor.material.specular = 0.1f;
  items.push_back(floor);
  for (int k = 0; k < 5; ++k) {
    DrawItem item;
    item.mesh_id = box;
    item.world_from_object = Translation(-120 + 60 * k, 30 * std::sin(k), 12.5 + 10 * (k % 2)) *
                             Eigen::AngleAxisd(0.5 * k, Eigen::Vector3d(0.2, 0.3, 1).normalized());
    item.instance_id = static_cast<uint16_t>(k + 1);
    item.material.color = {0.75f, 0.75f, 0.78f};
    item.material.shininess = 16 + 16 * k;
    items.push_back(item);
  }
  Light key;
  key.direction_world = Eigen::Vector3f(0.4f, 0.5f, -1.f).normalized();
  Light fill;
  fill.direction_world = Eigen::Vector3f(-0.6f, 0.2f, -0.5f).normalized();
  fill.ambient = 0.05f;
  fill.diffuse = 0.3f;
  fill.specular = 0.1f;
  const RenderResult result = renderer.Render(camera, {key, fill}, {0.1f, 0.12f, 0.15f}, items);
  cv::Mat bgr;
  cv::cvtColor(result.color, bgr, cv::COLOR_RGB2BGR);

  const std::string golden_path =
      std::string(STACKGEN_SOURCE_DIR) + "/tests/fixtures/render/boxes_golden.png";
  const char* update = std::getenv("STACKGEN_UPDATE_GOLDEN");
  if (update != nullptr && std::string(update) == "1") {
    ASSERT_TRUE(cv::imwrite(golden_path, bgr)) << golden_path;
  }
  const cv::Mat golden = cv::imread(golden_path, cv::IMREAD_COLOR);
  ASSERT_FALSE(golden.empty()) << "cannot read " << golden_path;
  ASSERT_EQ(golden.size(), bgr.size());

  // tolerance: renderers differ a little in shading and on edges
  cv::Mat diff;
  cv::absdiff(bgr, golden, diff);
  cv::Mat diff_gray;
  cv::cvtColor(diff, diff_gray, cv::COLOR_BGR2GRAY);
  const double mean_diff = cv::mean(diff_gray)[0];
  const int large_diffs = cv::countNonZero(diff_gray > 24);
  const bool matches = mean_diff < 1.5 && large_diffs < static_cast<int>(bgr.total() / 100);
  if (!matches) {
    const std::string diff_path = ::testing::TempDir() + "render_boxes_diff.png";
    const std::string actual_path = ::testing::TempDir() + "render_boxes_actual.png";
    cv::imwrite(diff_path, diff * 4);
    cv::imwrite(actual_path, bgr);
    ADD_FAILURE() << "image differs from " << golden_path << ": mean " << mean_diff << ", "
                  << large_diffs << " pixels off by > 24; see " << diff_path << " and "
                  << actual_path;
  }
}

}  // namespace
}  // namespace stackgen
