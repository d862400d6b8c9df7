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

#include "gen/mesh/mesh.h"
#include "tests/support/golden.h"
#include "tests/support/meshes.h"

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

// options with a plain background colour (display RGB), everything else default
RenderOptions Background(const Eigen::Vector3f& rgb) {
  RenderOptions options;
  options.background_rgb = rgb;
  return options;
}

// a light that shows surface colours as they are: ambient 1, no diffuse or highlight
std::vector<Light> FlatLight() {
  Light light;
  light.ambient = 1;
  light.diffuse = 0;
  light.specular = 0;
  return {light};
}

// a file under tests/fixtures/
std::string FixturePath(const std::string& name) {
  return std::string(STACKGEN_SOURCE_DIR) + "/tests/fixtures/" + name;
}

// the textured box fixture: a cube (2 units, here 100 mm) whose top face shows quadrants.png
// (red top left, green top right, blue bottom left, white bottom right) with u along +x, v along +y
TriangleMesh TexturedBox() {
  return LoadMesh(FixturePath("models/textured_box/textured_box.obj"), 50.0);
}

// the RGB colour at the pixel nearest to a world point
cv::Vec3b ColorAt(const RenderResult& result, const CameraModel& camera,
                  const Eigen::Vector3d& point_world) {
  const Eigen::Vector2d uv = Project(camera, point_world);
  return result.color.at<cv::Vec3b>(static_cast<int>(std::lround(uv.y())),
                                    static_cast<int>(std::lround(uv.x())));
}

// largest per-channel difference between two colours
int ColorDistance(const cv::Vec3b& a, const cv::Vec3b& b) {
  int distance = 0;
  for (int c = 0; c < 3; ++c) distance = std::max(distance, std::abs(a[c] - b[c]));
  return distance;
}

// true when two images of any type are equal in every byte
bool Identical(const cv::Mat& a, const cv::Mat& b) {
  if (a.size() != b.size() || a.type() != b.type()) return false;
  cv::Mat difference;
  cv::compare(a.reshape(1), b.reshape(1), difference, cv::CMP_NE);
  return cv::countNonZero(difference) == 0;
}

// the world point of pixel (u, v) from its depth
Eigen::Vector3d WorldPoint(const CameraModel& camera, const RenderResult& result, int u, int v) {
  const double z = result.depth_mm.at<float>(v, u);
  return camera.world_from_camera *
         Eigen::Vector3d((u - camera.cx) / camera.fx * z, (v - camera.cy) / camera.fy * z, z);
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

  const RenderResult result = renderer.Render(camera, FrontLights(), Background(background), items);
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

// with no lights (and shadows asked for) surfaces are black but still drawn, with their ids
TEST(RendererTest, NoLightsDrawsBlackSurfaces) {
  Renderer renderer(160, 120);
  const int box = renderer.AddMesh(MakeBox({60, 60, 60}));
  DrawItem item;
  item.mesh_id = box;
  item.instance_id = 3;
  item.world_from_object = Translation(0, 0, 30);
  RenderOptions options = Background({0.5f, 0.5f, 0.5f});
  options.shadows = true;
  const RenderResult result = renderer.Render(CameraLookingDown(1000), {}, options, {item});
  const cv::Mat drawn = result.instance == 3;
  ASSERT_GT(cv::countNonZero(drawn), 100);
  cv::Mat gray;
  cv::cvtColor(result.color, gray, cv::COLOR_RGB2GRAY);
  double most = 0;
  cv::minMaxLoc(gray, nullptr, &most, nullptr, nullptr, drawn);
  EXPECT_EQ(most, 0);
}

// depth is the camera z of the surface to 0.05 mm; background depth is 0
TEST(RendererTest, DepthIsExact) {
  Renderer renderer(640, 480);
  const int square = renderer.AddMesh(testing::MakeSquare(400));
  const CameraModel camera = CameraLookingDown(1000);
  DrawItem plane;
  plane.mesh_id = square;
  plane.instance_id = 1;

  // a plane facing the camera 1000 mm away
  RenderResult result = renderer.Render(camera, FrontLights(), RenderOptions(), {plane});
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
  renderer.Render(camera, FrontLights(), RenderOptions(), {plane}, &result);
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
  const RenderResult result = renderer.Render(camera, FrontLights(), RenderOptions(), items);

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
  const int square = renderer.AddMesh(testing::MakeSquare(1000));
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

  const RenderResult result =
      renderer.Render(camera, FrontLights(), Background({0.2f, 0.2f, 0.2f}), items);
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
      renderer.Render(camera, FrontLights(), Background({0.2f, 0.2f, 0.2f}), {half_hidden});
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
  const RenderResult result = renderer.Render(camera, FrontLights(), RenderOptions(), items);
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
  const int square = renderer.AddMesh(testing::MakeSquare(100));
  const CameraModel camera;  // identity pose: looking along +z

  // a closed box: its near face, 50 mm in front of its centre, 800 * 100 / 950 = 84.2 px wide
  const int face_px = 84;
  for (const int mesh_id : {box, inverted_box}) {
    DrawItem item;
    item.mesh_id = mesh_id;
    item.world_from_object = Translation(0, 0, 1000);
    item.instance_id = 1;
    const RenderResult result = renderer.Render(camera, FrontLights(), RenderOptions(), {item});
    EXPECT_NEAR(result.depth_mm.at<float>(240, 320), 950.0, 0.05) << "mesh " << mesh_id;
    EXPECT_EQ(cv::countNonZero(result.instance == 1), face_px * face_px) << "mesh " << mesh_id;
    EXPECT_EQ(cv::countNonZero(renderer.RenderSilhouettes(camera, {item})[0]), face_px * face_px);
  }

  // a square whose normal points away from the camera is still drawn (100 px wide)
  DrawItem item;
  item.mesh_id = square;
  item.world_from_object = Translation(0, 0, 800);
  item.instance_id = 2;
  const RenderResult result = renderer.Render(camera, FrontLights(), RenderOptions(), {item});
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
    EXPECT_THROW(renderer.Render(camera, FrontLights(), RenderOptions(), {item}),
                 std::runtime_error);
    EXPECT_THROW(renderer.RenderSilhouettes(camera, {item}), std::runtime_error);
  }
  TriangleMesh broken = MakeBox({10, 10, 10});
  broken.triangles.push_back({0, 1, 99});
  EXPECT_THROW(renderer.AddMesh(broken), std::runtime_error);
  EXPECT_THROW(renderer.AddMesh(TriangleMesh()), std::runtime_error);
  CameraModel bad_camera;
  bad_camera.near_mm = 0;
  EXPECT_THROW(renderer.Render(bad_camera, FrontLights(), RenderOptions(), {}), std::runtime_error);
  EXPECT_THROW(Renderer(0, 10), std::runtime_error);

  // textures and materials: unknown ids, a texture without texture coordinates, counts
  EXPECT_THROW(renderer.AddTexture(cv::Mat(4, 4, CV_8UC1, cv::Scalar(0))), std::runtime_error);
  EXPECT_THROW(renderer.AddTexture(cv::Mat()), std::runtime_error);
  const int texture = renderer.AddTexture(cv::Mat(4, 4, CV_8UC3, cv::Scalar(10, 20, 30)));
  DrawItem item;
  item.mesh_id = box;
  item.material.texture_id = texture;  // the box has no uvs
  EXPECT_THROW(renderer.Render(camera, FrontLights(), RenderOptions(), {item}), std::runtime_error);
  item.material.texture_id = texture + 1;
  EXPECT_THROW(renderer.Render(camera, FrontLights(), RenderOptions(), {item}), std::runtime_error);
  TriangleMesh textured = TexturedBox();
  textured.uvs.clear();
  EXPECT_THROW(renderer.AddMesh(textured), std::runtime_error);
  textured = TexturedBox();
  textured.uvs.pop_back();
  EXPECT_THROW(renderer.AddMesh(textured), std::runtime_error);
  textured = TexturedBox();
  textured.triangle_material.pop_back();
  EXPECT_THROW(renderer.AddMesh(textured), std::runtime_error);
  textured = TexturedBox();
  textured.triangle_material[0] = 2;
  EXPECT_THROW(renderer.AddMesh(textured), std::runtime_error);

  // options and lights
  item.material.texture_id = -1;
  RenderOptions options;
  options.shadows = true;
  options.shadow_map_size = 100;
  EXPECT_THROW(renderer.Render(camera, FrontLights(), options, {item}), std::runtime_error);
  Light point;
  point.type = Light::Type::kPoint;
  point.position_world.x() = std::nanf("");
  EXPECT_THROW(renderer.Render(camera, {point}, RenderOptions(), {item}), std::runtime_error);
  Light zero;
  zero.direction_world.setZero();
  EXPECT_THROW(renderer.Render(camera, {zero}, RenderOptions(), {item}), std::runtime_error);
}

// the framebuffer follows the camera size, and two renderers on one thread do not mix
TEST(RendererTest, ResizesAndSwitchesContexts) {
  Renderer first(640, 480);
  Renderer second(320, 240);
  const int box_first = first.AddMesh(MakeBox({50, 50, 50}));
  const int box_second = second.AddMesh(testing::MakeSquare(2000));
  DrawItem item;
  item.instance_id = 3;
  item.world_from_object = Translation(0, 0, 500);

  CameraModel small;
  small.width = 160;
  small.height = 120;
  small.cx = 79.5;
  small.cy = 59.5;
  item.mesh_id = box_first;
  const RenderResult a = first.Render(small, FrontLights(), RenderOptions(), {item});
  item.mesh_id = box_second;
  const RenderResult b = second.Render(CameraModel(), FrontLights(), RenderOptions(), {item});
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

// a textured OBJ (MTL with map_Kd, PNG texture) shows its texture the right way round: each
// quadrant of the image where it is in the file, not mirrored or flipped; the textured surface
// covers exactly its silhouette
TEST(RendererTest, TexturedObjShowsItsTexture) {
  Renderer renderer(640, 480);
  const int box = renderer.AddMesh(TexturedBox());
  const CameraModel camera = CameraLookingDown(1000);
  DrawItem item;
  item.mesh_id = box;
  item.instance_id = 1;
  const RenderResult result = renderer.Render(camera, FlatLight(), RenderOptions(), {item});
  EXPECT_EQ(
      cv::countNonZero((result.instance == 1) != renderer.RenderSilhouettes(camera, {item})[0]), 0);

  // the top face (z = 50 mm) seen from above: image up is world +y, image right world +x
  const std::vector<std::pair<Eigen::Vector3d, cv::Vec3b>> quadrants = {
      {{-25, 25, 50}, {255, 0, 0}},     // top left: red
      {{25, 25, 50}, {0, 255, 0}},      // top right: green
      {{-25, -25, 50}, {0, 0, 255}},    // bottom left: blue
      {{25, -25, 50}, {255, 255, 255}}  // bottom right: white
  };
  for (const auto& [point, expected] : quadrants) {
    const cv::Vec3b actual = ColorAt(result, camera, point);
    EXPECT_LE(ColorDistance(actual, expected), 3)
        << "at " << point.transpose() << ": " << actual << ", expected " << expected;
  }
}

// use_mesh_materials = false draws the whole mesh with item.material, its texture from
// AddTexture shown the same way round; changing materials changes neither ids nor depth
TEST(RendererTest, ItemMaterialReplacesMeshMaterials) {
  Renderer renderer(640, 480);
  const TriangleMesh mesh = TexturedBox();
  const int box = renderer.AddMesh(mesh);
  const CameraModel camera = CameraLookingDown(1000);
  DrawItem item;
  item.mesh_id = box;
  item.instance_id = 1;
  const RenderResult own = renderer.Render(camera, FlatLight(), RenderOptions(), {item});

  // a plain colour everywhere the box is
  item.use_mesh_materials = false;
  item.material.color = {0.2f, 0.6f, 0.4f};
  const RenderResult plain = renderer.Render(camera, FlatLight(), RenderOptions(), {item});
  EXPECT_TRUE(Identical(plain.instance, own.instance));
  EXPECT_TRUE(Identical(plain.depth_mm, own.depth_mm));
  const cv::Vec3b expected(51, 153, 102);
  int box_pixels = 0;
  for (int v = 0; v < plain.color.rows; ++v) {
    for (int u = 0; u < plain.color.cols; ++u) {
      if (plain.instance.at<uint16_t>(v, u) != 1) continue;
      ++box_pixels;
      ASSERT_LE(ColorDistance(plain.color.at<cv::Vec3b>(v, u), expected), 1)
          << "pixel " << u << "," << v;
    }
  }
  EXPECT_GT(box_pixels, 5000);

  // the same texture through AddTexture and item.material: the same image as the mesh's own
  const int label = mesh.materials[0].texture.empty() ? 1 : 0;
  item.material.color = {1, 1, 1};
  item.material.texture_id = renderer.AddTexture(mesh.materials[label].texture);
  const RenderResult textured = renderer.Render(camera, FlatLight(), RenderOptions(), {item});
  EXPECT_TRUE(Identical(textured.instance, own.instance));
  EXPECT_TRUE(Identical(textured.depth_mm, own.depth_mm));
  EXPECT_LE(ColorDistance(ColorAt(textured, camera, {-25, 25, 50}), {255, 0, 0}), 3);
  EXPECT_LE(ColorDistance(ColorAt(textured, camera, {25, -25, 50}), {255, 255, 255}), 3);
  cv::Mat difference;
  cv::absdiff(textured.color, own.color, difference);
  EXPECT_EQ(cv::countNonZero(difference.reshape(1) > 1), 0);
}

// a material gain scales the colour (display values, clamped) of mesh and item materials alike,
// and changes neither the pixels covered, their ids nor their depth
TEST(RendererTest, MaterialGainChangesColourOnly) {
  Renderer renderer(640, 480);
  const int textured_box = renderer.AddMesh(TexturedBox());
  const int box = renderer.AddMesh(MakeBox({60, 60, 60}));
  const CameraModel camera = CameraLookingDown(1000);
  DrawItem textured;
  textured.mesh_id = textured_box;
  textured.instance_id = 1;
  textured.world_from_object = Translation(-80, 0, 0);
  DrawItem plain;
  plain.mesh_id = box;
  plain.instance_id = 2;
  plain.world_from_object = Translation(100, 0, 30);
  plain.material.color = {0.4f, 0.8f, 0.6f};
  const RenderResult before =
      renderer.Render(camera, FlatLight(), RenderOptions(), {textured, plain});

  textured.gain.color = {1, 0.5f, 1};
  plain.gain.color = {0.5f, 2, 1};  // 0.8 x 2 clamps to 1
  plain.gain.specular = 0.1f;
  plain.gain.shininess = 3;
  const RenderResult after =
      renderer.Render(camera, FlatLight(), RenderOptions(), {textured, plain});
  EXPECT_TRUE(Identical(after.instance, before.instance));
  EXPECT_TRUE(Identical(after.depth_mm, before.depth_mm));

  // green halved on the texture: red stays, white turns magenta-ish
  EXPECT_LE(ColorDistance(ColorAt(after, camera, {-105, 25, 50}), {255, 0, 0}), 3);
  EXPECT_LE(ColorDistance(ColorAt(after, camera, {-55, 25, 50}), {0, 128, 0}), 3);
  EXPECT_LE(ColorDistance(ColorAt(after, camera, {-55, -25, 50}), {255, 128, 255}), 3);
  EXPECT_LE(ColorDistance(ColorAt(after, camera, {100, 0, 60}), {51, 255, 153}), 2);
  EXPECT_LE(ColorDistance(ColorAt(before, camera, {100, 0, 60}), {102, 204, 153}), 2);
}

// shadows: a box above a floor, one resting on it and a 1 mm plate 1 mm above it (seen through
// a long lens, 0.25 mm per pixel), under a tilted light, darken exactly the floor in their
// predicted shadows to its ambient term, right up to the box's foot and the plate's edge (no
// peter-panning: the plate's top is 2.8 mm from the floor along the light); every other pixel
// (lit floor, the boxes themselves: no acne) keeps its colour, and ids and depth are the same
// with shadows on and off
TEST(RendererTest, ShadowsDarkenOnlyTheShadowedFloor) {
  Renderer renderer(640, 480);
  const int square = renderer.AddMesh(testing::MakeSquare(600));
  const Eigen::Vector3f floor_color(0.8f, 0.7f, 0.6f);
  Light light;  // travels +x as it falls: a point p shadows (p.x + p.z, p.y, 0)
  light.direction_world = Eigen::Vector3f(1, 0, -1).normalized();
  light.ambient = 0.3f;
  light.diffuse = 0.7f;
  light.specular = 0.3f;

  // 60 x 60 mm boxes left of the camera, so it sees their right sides and the floor beside them
  struct Caster {
    int height_mm;
    int bottom_mm;
    double focal_px;  // of the camera, 1000 mm above (camera_x_mm, 0)
    double camera_x_mm;
    int min_shadowed_pixels;  // about 2/3 of those in the visible umbra
  };
  const Caster casters[] = {{60, 50, 800, 0, 2000}, {60, 0, 800, 0, 1500}, {1, 1, 4000, -120, 600}};
  for (const Caster& caster : casters) {
    const std::string what = "box " + std::to_string(caster.height_mm) + " mm high at " +
                             std::to_string(caster.bottom_mm) + " mm";
    CameraModel camera = CameraLookingDown(1000);
    camera.fx = camera.fy = caster.focal_px;
    camera.world_from_camera.translation().x() = caster.camera_x_mm;
    DrawItem floor;
    floor.mesh_id = square;
    floor.instance_id = 1;
    floor.material.color = floor_color;
    DrawItem cube;
    cube.mesh_id = renderer.AddMesh(MakeBox({60, 60, static_cast<float>(caster.height_mm)}));
    cube.instance_id = 2;
    cube.world_from_object = Translation(-150, 0, caster.bottom_mm + caster.height_mm / 2.0);
    RenderOptions options;
    const RenderResult off = renderer.Render(camera, {light}, options, {floor, cube});
    options.shadows = true;
    const RenderResult on = renderer.Render(camera, {light}, options, {floor, cube});
    ASSERT_TRUE(Identical(on.instance, off.instance)) << what;
    ASSERT_TRUE(Identical(on.depth_mm, off.depth_mm)) << what;
    // the unoccluded box covers exactly its silhouette in the shadowed render too
    const std::vector<cv::Mat> silhouettes = renderer.RenderSilhouettes(camera, {floor, cube});
    EXPECT_EQ(cv::countNonZero((on.instance == 2) != silhouettes[1]), 0) << what;

    // the shadow on the floor: x from -180 + bottom to -120 + top, |y| <= 30; 1 mm inside its
    // edges in full shadow, 2 mm outside untouched
    const int top = caster.bottom_mm + caster.height_mm;
    const Eigen::AlignedBox2d shadow(Eigen::Vector2d(-180 + caster.bottom_mm, -30),
                                     Eigen::Vector2d(-120 + top, 30));
    const Eigen::AlignedBox2d umbra(shadow.min().array() + 1, shadow.max().array() - 1);
    const Eigen::AlignedBox2d penumbra(shadow.min().array() - 2, shadow.max().array() + 2);
    const float ambient_scale = 255 * std::sqrt(light.ambient);
    const cv::Vec3b ambient_only(
        static_cast<uint8_t>(std::lround(ambient_scale * floor_color.x())),
        static_cast<uint8_t>(std::lround(ambient_scale * floor_color.y())),
        static_cast<uint8_t>(std::lround(ambient_scale * floor_color.z())));
    int shadowed = 0;
    int unchanged = 0;
    for (int v = 0; v < on.color.rows; ++v) {
      for (int u = 0; u < on.color.cols; ++u) {
        const int id = on.instance.at<uint16_t>(v, u);
        const cv::Vec3b with = on.color.at<cv::Vec3b>(v, u);
        const cv::Vec3b without = off.color.at<cv::Vec3b>(v, u);
        const Eigen::Vector3d p = WorldPoint(camera, on, u, v);
        const Eigen::Vector2d xy = p.head<2>();
        if (id == 1 && umbra.contains(xy)) {
          ++shadowed;
          ASSERT_LE(ColorDistance(with, ambient_only), 2)
              << what << ": shadowed pixel " << u << "," << v << " " << with;
          ASSERT_GT(without[0], with[0] + 40) << what << ": pixel " << u << "," << v;
        } else if (id != 1 || !penumbra.contains(xy)) {
          ++unchanged;
          ASSERT_EQ(with, without)
              << what << ": pixel " << u << "," << v << " (id " << id << ") at " << p.transpose();
        }
      }
    }
    // the visible shadow beside the box is a decent area; most of the image is unchanged
    EXPECT_GT(shadowed, caster.min_shadowed_pixels) << what;
    EXPECT_GT(unchanged, 640 * 480 * 9 / 10) << what;
  }
}

// a point light just above one end of a floor lights that end brighter than the far end, as n.l
// says; a directional light lights the floor evenly; without occluders, shadows change nothing
TEST(RendererTest, PointLightDirectionVariesOverTheFloor) {
  Renderer renderer(640, 480);
  const int square = renderer.AddMesh(testing::MakeSquare(600));
  const CameraModel camera = CameraLookingDown(1000);
  DrawItem floor;
  floor.mesh_id = square;
  floor.instance_id = 1;
  floor.material.color = {0.8f, 0.8f, 0.8f};
  floor.material.specular = 0;
  Light point;
  point.type = Light::Type::kPoint;
  point.position_world = {-250, 0, 100};
  point.ambient = 0;
  point.diffuse = 1;
  point.specular = 0;
  Light directional = point;
  directional.type = Light::Type::kDirectional;
  directional.direction_world = Eigen::Vector3f(0.3f, 0, -1).normalized();

  // point: n.l = 1 under the light, 100 / |(-500, 0, 100)| at the far end (no falloff)
  const RenderResult lit = renderer.Render(camera, {point}, RenderOptions(), {floor});
  const int near = ColorAt(lit, camera, {-250, 0, 0})[0];
  const int far = ColorAt(lit, camera, {250, 0, 0})[0];
  EXPECT_NEAR(near, 255 * 0.8, 2);
  EXPECT_NEAR(far, 255 * 0.8 * std::sqrt(100 / std::hypot(500.0, 100.0)), 2);
  EXPECT_GT(near, far + 50);

  // directional: the same colour everywhere on the floor
  const RenderResult even = renderer.Render(camera, {directional}, RenderOptions(), {floor});
  double min_value = 0;
  double max_value = 0;
  cv::Mat red;
  cv::extractChannel(even.color, red, 0);
  cv::minMaxLoc(red, &min_value, &max_value, nullptr, nullptr, even.instance == 1);
  EXPECT_LE(max_value - min_value, 1);
  EXPECT_NEAR(max_value, 255 * 0.8 * std::sqrt(1 / std::sqrt(1.09)), 2);

  // a floor alone casts no shadow on itself, under either light (no acne)
  RenderOptions shadows;
  shadows.shadows = true;
  EXPECT_TRUE(Identical(renderer.Render(camera, {point}, shadows, {floor}).color, lit.color));
  EXPECT_TRUE(
      Identical(renderer.Render(camera, {directional}, shadows, {floor}).color, even.color));
}

// a background image shows exactly, unshaded, where nothing is drawn, and nowhere else; an
// image of the wrong size or type is refused
TEST(RendererTest, BackgroundImageShowsWhereNothingIsDrawn) {
  Renderer renderer(640, 480);
  const int box = renderer.AddMesh(MakeBox({100, 100, 100}));
  const int square = renderer.AddMesh(testing::MakeSquare(200));
  const CameraModel camera = CameraLookingDown(1000);
  DrawItem object;
  object.mesh_id = box;
  object.instance_id = 1;
  object.world_from_object = Translation(-100, 0, 50);
  DrawItem prop;  // not an object (id 0) but drawn
  prop.mesh_id = square;
  prop.world_from_object = Translation(150, 0, 0);
  const std::vector<DrawItem> items = {object, prop};

  cv::Mat image(480, 640, CV_8UC3);
  cv::RNG(7).fill(image, cv::RNG::UNIFORM, 0, 256);
  RenderOptions options;
  options.background_rgb = {0.5f, 0.5f, 0.5f};
  const RenderResult plain = renderer.Render(camera, FrontLights(), options, items);
  options.background_image = image;
  const RenderResult result = renderer.Render(camera, FrontLights(), options, items);
  EXPECT_TRUE(Identical(result.instance, plain.instance));
  EXPECT_TRUE(Identical(result.depth_mm, plain.depth_mm));
  int background_pixels = 0;
  int prop_pixels = 0;
  for (int v = 0; v < result.color.rows; ++v) {
    for (int u = 0; u < result.color.cols; ++u) {
      const cv::Vec3b color = result.color.at<cv::Vec3b>(v, u);
      if (result.depth_mm.at<float>(v, u) == 0) {
        ++background_pixels;
        ASSERT_EQ(color, image.at<cv::Vec3b>(v, u)) << "background pixel " << u << "," << v;
      } else {
        prop_pixels += result.instance.at<uint16_t>(v, u) == 0 ? 1 : 0;
        ASSERT_EQ(color, plain.color.at<cv::Vec3b>(v, u)) << "drawn pixel " << u << "," << v;
      }
    }
  }
  EXPECT_GT(background_pixels, 100000);
  EXPECT_GT(prop_pixels, 10000);  // drawn with id 0: not background

  // wrong size, wrong type
  options.background_image = cv::Mat(240, 320, CV_8UC3, cv::Scalar(0));
  EXPECT_THROW(renderer.Render(camera, FrontLights(), options, items), std::runtime_error);
  options.background_image = cv::Mat(480, 640, CV_8UC4, cv::Scalar(0));
  EXPECT_THROW(renderer.Render(camera, FrontLights(), options, items), std::runtime_error);
}

// a fixed scene matches the golden image within a tolerance (a diff image is written on
// failure); STACKGEN_UPDATE_GOLDEN=1 rewrites the golden image
TEST(RendererTest, MatchesGoldenImage) {
  Renderer renderer(320, 240);
  const int box = renderer.AddMesh(MakeBox({60, 40, 25}));
  const int square = renderer.AddMesh(testing::MakeSquare(600));
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
  const RenderResult result =
      renderer.Render(camera, {key, fill}, Background({0.1f, 0.12f, 0.15f}), items);
  cv::Mat bgr;
  cv::cvtColor(result.color, bgr, cv::COLOR_RGB2BGR);

  testing::ExpectMatchesGolden(bgr, "render/boxes_golden.png", "render_boxes");
}

}  // namespace
}  // namespace stackgen
