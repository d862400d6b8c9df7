// Physically based frames of gen/render/renderer.cc: energy, reflection, anti-aliasing and the
// labels that must not depend on them.
#include <algorithm>
#include <cmath>
#include <string>
#include <vector>

#include <gtest/gtest.h>
#include <opencv2/core.hpp>
#include <opencv2/imgproc.hpp>

#include "gen/render/environment.h"
#include "gen/render/renderer.h"
#include "tests/support/cameras.h"
#include "tests/support/environments.h"
#include "tests/support/golden.h"
#include "tests/support/meshes.h"

namespace stackgen {
namespace {

// a UV sphere of `radius_mm` centred at the origin, smooth normals, wound outwards
TriangleMesh MakeSphere(float radius_mm, int rings = 64, int segments = 128) {
  TriangleMesh mesh;
  for (int i = 0; i <= rings; ++i) {
    const double theta = M_PI * i / rings;
    for (int j = 0; j <= segments; ++j) {
      const double phi = 2 * M_PI * j / segments;
      const Eigen::Vector3f n(static_cast<float>(std::sin(theta) * std::cos(phi)),
                              static_cast<float>(std::sin(theta) * std::sin(phi)),
                              static_cast<float>(std::cos(theta)));
      mesh.positions_mm.push_back(radius_mm * n);
      mesh.normals.push_back(n);
    }
  }
  const auto index = [segments](int i, int j) {
    return static_cast<uint32_t>(i * (segments + 1) + j);
  };
  for (int i = 0; i < rings; ++i) {
    for (int j = 0; j < segments; ++j) {
      // no triangles with two corners on a pole
      if (i + 1 < rings)
        mesh.triangles.push_back({index(i, j), index(i + 1, j), index(i + 1, j + 1)});
      if (i > 0) mesh.triangles.push_back({index(i, j), index(i + 1, j + 1), index(i, j + 1)});
    }
  }
  return mesh;
}

using testing::CameraLookingDown;

// an environment whose radiance is `f` of the direction, prefiltered
template <typename F>
PrefilteredEnvironment PrefilteredOf(F f, int height = 128) {
  return Prefilter(testing::EnvironmentOf(f, height), 2 * height);
}

// the furnace: an environment of `radiance` in every direction, added to `renderer`
int AddFurnace(Renderer* renderer, float radiance) {
  return renderer->AddEnvironment(
      PrefilteredOf([&](const Eigen::Vector3d&) { return Eigen::Vector3f::Constant(radiance); }));
}

// a white item of the given metallic and roughness
DrawItem WhiteItem(int mesh_id, float metallic, float roughness, uint16_t id = 1) {
  DrawItem item;
  item.mesh_id = mesh_id;
  item.instance_id = id;
  item.material.color = Eigen::Vector3f::Ones();
  item.material.metallic = metallic;
  item.material.roughness = roughness;
  return item;
}

RenderOptions PbrOptions(int environment_id, int msaa_samples = 1) {
  RenderOptions options;
  options.shading = Shading::kPbr;
  options.environment_id = environment_id;
  options.msaa_samples = msaa_samples;
  return options;
}

bool Identical(const cv::Mat& a, const cv::Mat& b) {
  if (a.size() != b.size() || a.type() != b.type()) return false;
  cv::Mat difference;
  cv::compare(a.reshape(1), b.reshape(1), difference, cv::CMP_NE);
  return cv::countNonZero(difference) == 0;
}

// the furnace test: in a uniform environment a white sphere, metal or not, smooth or rough,
// reflects exactly the environment's radiance: no energy gained, little lost (the energy
// compensation puts back what single scattering loses on rough metal)
TEST(RendererPbrTest, WhiteFurnaceGainsNoEnergyAndLosesLittle) {
  Renderer renderer(320, 240);
  const int sphere = renderer.AddMesh(MakeSphere(60));
  const float radiance = 0.5f;
  const int furnace = AddFurnace(&renderer, radiance);
  const CameraModel camera = CameraLookingDown(300);
  for (const float metallic : {0.f, 1.f}) {
    for (const float roughness : {0.05f, 0.25f, 0.5f, 0.75f, 1.f}) {
      const RenderResult result = renderer.Render(camera, {}, PbrOptions(furnace),
                                                  {WhiteItem(sphere, metallic, roughness)});
      double lowest = 1e9;
      double highest = 0;
      int pixels = 0;
      for (int v = 0; v < camera.height; ++v) {
        for (int u = 0; u < camera.width; ++u) {
          if (result.instance.at<uint16_t>(v, u) != 1) continue;
          const cv::Vec3f c = result.color_linear.at<cv::Vec3f>(v, u);
          for (int k = 0; k < 3; ++k) {
            lowest = std::min<double>(lowest, c[k]);
            highest = std::max<double>(highest, c[k]);
          }
          ++pixels;
        }
      }
      SCOPED_TRACE("metallic " + std::to_string(metallic) + ", roughness " +
                   std::to_string(roughness));
      EXPECT_GT(pixels, 20000);
      EXPECT_LE(highest, radiance * 1.01);
      EXPECT_GE(lowest, radiance * 0.97);
    }
  }
}

// a classic material's two colours (MeshMaterial::metal_color): a dark diffuse colour and a
// white metal colour give, in the furnace, a metal sphere as bright as the environment and a
// dielectric one dark
TEST(RendererPbrTest, MetalColourWhereMetalDiffuseColourWhereNot) {
  Renderer renderer(320, 240);
  const int sphere = renderer.AddMesh(MakeSphere(60));
  const float radiance = 0.5f;
  const int furnace = AddFurnace(&renderer, radiance);
  const CameraModel camera = CameraLookingDown(300);
  for (const float metallic : {0.f, 1.f}) {
    DrawItem item = WhiteItem(sphere, metallic, 0.4f);
    item.material.color = Eigen::Vector3f::Constant(0.2f);
    item.material.metal_color = Eigen::Vector3f::Ones();
    const RenderResult result = renderer.Render(camera, {}, PbrOptions(furnace), {item});
    const cv::Scalar mean = cv::mean(result.color_linear, result.instance == 1);
    SCOPED_TRACE("metallic " + std::to_string(metallic));
    if (metallic == 1.f) {
      EXPECT_NEAR(mean[0], radiance, 0.03 * radiance);
    } else {
      // the diffuse lobe of 0.2 (0.033 in linear light) and a 4 % highlight
      EXPECT_LT(mean[0], 0.2 * radiance);
    }
  }
}

// each kind of surface detail draws its own pattern on a plate (none, cast, brushed, scuffed,
// moulded and wood all differ somewhere), and no detail moves a label: ids and depth stay
// byte-identical
TEST(RendererPbrTest, SurfaceDetailKindsDifferAndLeaveLabels) {
  Renderer renderer(320, 240);
  const int plate = renderer.AddMesh(testing::MakeSquare(200));
  const int environment = renderer.AddEnvironment(PrefilteredOf(
      [](const Eigen::Vector3d& d) { return Eigen::Vector3f::Constant(d.z() > 0 ? 1.f : 0.2f); }));
  const CameraModel camera = CameraLookingDown(300);
  std::vector<RenderResult> results;
  for (const SurfaceDetail::Kind kind :
       {SurfaceDetail::Kind::kNone, SurfaceDetail::Kind::kCast, SurfaceDetail::Kind::kBrushed,
        SurfaceDetail::Kind::kScuffed, SurfaceDetail::Kind::kMoulded, SurfaceDetail::Kind::kWood}) {
    DrawItem item = WhiteItem(plate, 0.f, 0.5f);
    item.material.color = Eigen::Vector3f::Constant(0.4f);
    item.detail.kind = kind;
    item.detail.strength = 1.f;
    item.detail.scale_mm = 4.f;
    item.detail.offset = Eigen::Vector3f(3.f, 7.f, 11.f);
    results.push_back(renderer.Render(camera, {}, PbrOptions(environment), {item}));
  }
  for (size_t a = 0; a < results.size(); ++a) {
    EXPECT_TRUE(Identical(results[a].instance, results[0].instance)) << a;
    EXPECT_TRUE(Identical(results[a].depth_mm, results[0].depth_mm)) << a;
    for (size_t b = a + 1; b < results.size(); ++b) {
      cv::Mat difference;
      cv::absdiff(results[a].color_linear, results[b].color_linear, difference);
      double largest = 0;
      cv::minMaxLoc(difference.reshape(1), nullptr, &largest);
      EXPECT_GT(largest, 0.01) << "kinds " << a << " and " << b << " look the same";
    }
  }
}

// a mirror-like metal sphere shows the environment in the reflected direction, turned by the
// environment's yaw
TEST(RendererPbrTest, MirrorSphereReflectsTheEnvironment) {
  Renderer renderer(320, 240);
  const int sphere = renderer.AddMesh(MakeSphere(60));
  const auto gradient = [](const Eigen::Vector3d& d) {
    return Eigen::Vector3f(static_cast<float>(0.5 + 0.5 * d.x()),
                           static_cast<float>(0.5 + 0.5 * d.y()),
                           static_cast<float>(0.5 + 0.5 * d.z()));
  };
  const int environment = renderer.AddEnvironment(PrefilteredOf(gradient, 256));
  const CameraModel camera = CameraLookingDown(300);
  for (const double yaw_deg : {0.0, 90.0}) {
    RenderOptions options = PbrOptions(environment);
    options.environment_yaw_deg = yaw_deg;
    const RenderResult result = renderer.Render(camera, {}, options, {WhiteItem(sphere, 1.f, 0.f)});
    const Eigen::Matrix3d environment_from_world =
        Eigen::AngleAxisd(-yaw_deg * M_PI / 180, Eigen::Vector3d::UnitZ()).toRotationMatrix();
    double worst = 0;
    int checked = 0;
    const Eigen::Vector3d eye = camera.world_from_camera.translation();
    for (int v = 0; v < camera.height; v += 3) {
      for (int u = 0; u < camera.width; u += 3) {
        // the ray through the pixel centre, where it meets the sphere, and the reflection
        const Eigen::Vector3d ray =
            (camera.world_from_camera.linear() *
             Eigen::Vector3d((u - camera.cx) / camera.fx, (v - camera.cy) / camera.fy, 1))
                .normalized();
        const double b = eye.dot(ray);
        const double disc = b * b - (eye.squaredNorm() - 60.0 * 60.0);
        if (disc <= 0) continue;
        const Eigen::Vector3d n = (eye + (-b - std::sqrt(disc)) * ray).normalized();
        if (n.dot(-ray) < 0.5) continue;  // the rim: normals interpolated over facets
        const Eigen::Vector3d reflected = ray - 2 * ray.dot(n) * n;
        const Eigen::Vector3f expected = gradient(environment_from_world * reflected);
        const cv::Vec3f c = result.color_linear.at<cv::Vec3f>(v, u);
        for (int k = 0; k < 3; ++k) worst = std::max<double>(worst, std::abs(c[k] - expected[k]));
        ++checked;
      }
    }
    SCOPED_TRACE("yaw " + std::to_string(yaw_deg));
    EXPECT_GT(checked, 1000);
    EXPECT_LT(worst, 0.03);
  }
}

// multisampling smooths edges in colour only: ids and depth are byte-identical with it on or
// off, and the same as a Phong frame's
TEST(RendererPbrTest, AntiAliasedEdgesLeaveLabelsExact) {
  Renderer renderer(320, 240);
  const int square = renderer.AddMesh(testing::MakeSquare(100));
  const int furnace = renderer.AddEnvironment(
      PrefilteredOf([](const Eigen::Vector3d&) { return Eigen::Vector3f::Constant(0.8f); }, 32));
  const CameraModel camera = CameraLookingDown(300);
  DrawItem item = WhiteItem(square, 0.f, 1.f);
  // turned by 20 degrees, so its edges cross pixels at every phase
  item.world_from_object = Eigen::AngleAxisd(0.35, Eigen::Vector3d::UnitZ());
  const RenderResult sharp = renderer.Render(camera, {}, PbrOptions(furnace, 1), {item});
  const RenderResult smooth = renderer.Render(camera, {}, PbrOptions(furnace, 4), {item});
  const RenderResult phong = renderer.Render(camera, {}, RenderOptions(), {item});
  EXPECT_TRUE(Identical(sharp.instance, smooth.instance));
  EXPECT_TRUE(Identical(sharp.depth_mm, smooth.depth_mm));
  EXPECT_TRUE(Identical(sharp.instance, phong.instance));
  EXPECT_TRUE(Identical(sharp.depth_mm, phong.depth_mm));

  // without multisampling each pixel is the square's colour or black; with it, edge pixels
  // take values between, and the interior is unchanged
  const auto between = [](const cv::Mat& linear, float inside) {
    int count = 0;
    for (int v = 0; v < linear.rows; ++v) {
      for (int u = 0; u < linear.cols; ++u) {
        const float g = linear.at<cv::Vec3f>(v, u)[1];
        if (g > 0.05f * inside && g < 0.95f * inside) ++count;
      }
    }
    return count;
  };
  const float inside = sharp.color_linear.at<cv::Vec3f>(120, 160)[1];
  EXPECT_NEAR(inside, 0.8f, 0.01f);
  EXPECT_NEAR(smooth.color_linear.at<cv::Vec3f>(120, 160)[1], inside, 1e-3f);
  EXPECT_EQ(between(sharp.color_linear, inside), 0);
  EXPECT_GT(between(smooth.color_linear, inside), 300);  // about the square's perimeter in px
}

// a directional light of strength d shows a white matte surface facing it at about d, and the
// background image comes out as its decoded display values times background_scale
TEST(RendererPbrTest, LightsAndBackgroundInLinearLight) {
  Renderer renderer(320, 240);
  const int square = renderer.AddMesh(testing::MakeSquare(100));
  const CameraModel camera = CameraLookingDown(300);
  Light light;
  light.direction_world = Eigen::Vector3f(0, 0, -1);
  light.diffuse = 0.6f;
  RenderOptions options = PbrOptions(-1);
  options.background_image = cv::Mat(240, 320, CV_8UC3, cv::Scalar(188, 188, 188));
  options.background_scale = 2.f;
  const RenderResult result =
      renderer.Render(camera, {light}, options, {WhiteItem(square, 0.f, 1.f)});
  EXPECT_NEAR(result.color_linear.at<cv::Vec3f>(120, 160)[1], 0.6f, 0.06f);
  // display 188 / 255 is 0.5029 in linear light
  EXPECT_NEAR(result.color_linear.at<cv::Vec3f>(5, 5)[0], 2 * 0.5029f, 0.005f);
}

// a light's colour and the environment's multiply their linear light per channel: a white
// matte surface under an orange light of strength 0.6 is 0.6 x its colour, and in a uniform
// environment tinted (0.5, 1, 2) its radiance per channel times that
TEST(RendererPbrTest, ColouredLightsAndEnvironment) {
  Renderer renderer(320, 240);
  const int square = renderer.AddMesh(testing::MakeSquare(100));
  const CameraModel camera = CameraLookingDown(300);
  Light light;
  light.diffuse = 0.6f;
  light.color = Eigen::Vector3f(1.5f, 0.9f, 0.4f);
  const cv::Vec3f lit = renderer.Render(camera, {light}, PbrOptions(-1),
                                        {WhiteItem(square, 0.f, 1.f)})
                            .color_linear.at<cv::Vec3f>(120, 160);
  EXPECT_NEAR(lit[0], 0.6f * 1.5f, 0.08f);
  EXPECT_NEAR(lit[1], 0.6f * 0.9f, 0.06f);
  EXPECT_NEAR(lit[2], 0.6f * 0.4f, 0.03f);
  const float radiance = 0.5f;
  RenderOptions tinted = PbrOptions(AddFurnace(&renderer, radiance));
  tinted.environment_color = Eigen::Vector3f(0.5f, 1.f, 2.f);
  const cv::Vec3f seen =
      renderer.Render(camera, {}, tinted, {WhiteItem(square, 0.f, 1.f)}).color_linear.at<cv::Vec3f>(
          120, 160);
  EXPECT_NEAR(seen[0] / seen[1], 0.5f, 0.01f);
  EXPECT_NEAR(seen[2] / seen[1], 2.f, 0.04f);
  EXPECT_NEAR(seen[1], radiance, 0.05f);
  tinted.environment_color = Eigen::Vector3f(-1.f, 1.f, 1.f);
  EXPECT_THROW(renderer.Render(camera, {}, tinted, {}), std::runtime_error);
}

TEST(RendererPbrTest, BadOptionsThrow) {
  Renderer renderer(64, 48);
  const int square = renderer.AddMesh(testing::MakeSquare(100));
  CameraModel camera = CameraLookingDown(300, 64, 48);
  const std::vector<DrawItem> items = {WhiteItem(square, 0.f, 0.5f)};
  EXPECT_THROW(renderer.Render(camera, {}, PbrOptions(-1, 3), items), std::runtime_error);
  EXPECT_THROW(renderer.Render(camera, {}, PbrOptions(0), items), std::runtime_error);
  RenderOptions negative = PbrOptions(-1);
  negative.environment_intensity = -1;
  EXPECT_THROW(renderer.Render(camera, {}, negative, items), std::runtime_error);
  PrefilteredEnvironment broken;
  broken.name = "broken";
  EXPECT_THROW(renderer.AddEnvironment(broken), std::runtime_error);
}

// what surrounds a surface hides the environment from it (RenderOptions::environment_occlusion_mm):
// in the furnace a white floor beside a block 60 mm tall gets darker, the floor far from it and
// the block's top keep their light, nothing gets brighter, and depth and ids stay as they were
TEST(RendererPbrTest, EnvironmentOcclusionDarkensTheFloorBesideABlock) {
  Renderer renderer(320, 240);
  const int floor = renderer.AddMesh(testing::MakeSquare(400));
  const int block = renderer.AddMesh(testing::BoxMesh(Eigen::Vector3f(-30, -30, 0),
                                                      Eigen::Vector3f(30, 30, 60)));
  const int furnace = AddFurnace(&renderer, 0.5f);
  const CameraModel camera = CameraLookingDown(300);
  const std::vector<DrawItem> items = {WhiteItem(floor, 0.f, 1.f, 0), WhiteItem(block, 0.f, 1.f, 1)};
  RenderOptions options = PbrOptions(furnace, 4);
  const RenderResult open = renderer.Render(camera, {}, options, items);
  options.environment_occlusion_mm = 100;
  const RenderResult hidden = renderer.Render(camera, {}, options, items);
  EXPECT_TRUE(Identical(open.depth_mm, hidden.depth_mm));
  EXPECT_TRUE(Identical(open.instance, hidden.instance));
  // the green channel at floor point (x, y) mm, or at the block's top
  const auto at = [&](const RenderResult& result, double x_mm, double y_mm, double z_mm = 300) {
    const int u = static_cast<int>(std::lround(camera.cx + camera.fx * x_mm / z_mm));
    const int v = static_cast<int>(std::lround(camera.cy - camera.fy * y_mm / z_mm));
    return result.color_linear.at<cv::Vec3f>(v, u)[1];
  };
  EXPECT_LT(at(hidden, 42, 0), 0.85f * at(open, 42, 0));
  EXPECT_LT(at(hidden, 0, -42), 0.85f * at(open, 0, -42));
  EXPECT_NEAR(at(hidden, 0, 0, 240), at(open, 0, 0, 240), 0.01f * at(open, 0, 0, 240));
  EXPECT_NEAR(at(hidden, 110, 82), at(open, 110, 82), 0.01f * at(open, 110, 82));
  cv::Mat brighter;
  cv::compare(hidden.color_linear.reshape(1), open.color_linear.reshape(1) + 1e-4, brighter,
              cv::CMP_GT);
  EXPECT_EQ(cv::countNonZero(brighter), 0);
  // a radius that is not finite and >= 0 is refused
  options.environment_occlusion_mm = -1;
  EXPECT_THROW(renderer.Render(camera, {}, options, items), std::runtime_error);
}

// The width of a shadow's edge on the floor, mm (where the light rises from 10 % to 90 % of the
// lit floor's), and the light in the shadow beside it, as a share of the lit floor's: a 60 mm
// square `height_mm` over a white floor, lit at 45 degrees by a lamp of `radius_deg`, its
// shadow's far edge 30 + height_mm mm along x, seen from 300 mm straight above (0.75 mm a pixel;
// 20 rows around y = 0 averaged, which also averages the soft edge's grain out).
struct ShadowEdge {
  double width_mm = 0;
  double umbra = 0;  // at 5-12 mm past where the square hides the floor
};
ShadowEdge ShadowEdgeOf(Renderer* renderer, double height_mm, double radius_deg) {
  const int floor = renderer->AddMesh(testing::MakeSquare(400));
  const int plate = renderer->AddMesh(testing::MakeSquare(60));
  const CameraModel camera = CameraLookingDown(300);
  Light lamp;
  lamp.direction_world = Eigen::Vector3f(1, 0, -1).normalized();
  lamp.diffuse = 0.8f;
  lamp.radius_rad = static_cast<float>(radius_deg * M_PI / 180);
  RenderOptions options = PbrOptions(-1);
  options.shadows = true;
  DrawItem square = WhiteItem(plate, 0.f, 1.f, 1);
  square.world_from_object = Eigen::Translation3d(0, 0, height_mm) * Eigen::Isometry3d::Identity();
  const RenderResult result =
      renderer->Render(camera, {lamp}, options, {WhiteItem(floor, 0.f, 1.f, 0), square});
  // the floor's light at world x (mm) on the row of y = 0, 20 rows averaged
  const auto light_at = [&](double x_mm) {
    const int u = static_cast<int>(std::lround(camera.cx + camera.fx * x_mm / 300));
    double sum = 0;
    for (int v = 110; v < 130; ++v) sum += result.color_linear.at<cv::Vec3f>(v, u)[1];
    return sum / 20;
  };
  const double lit = light_at(110);
  // the first x past the square's hidden floor where the light passes a share of `lit`
  const double hidden_mm = 30 * 300 / (300 - height_mm);
  const auto crossing = [&](double share) {
    for (double x = hidden_mm + 1; x < 110; x += 0.25) {
      if (light_at(x) >= share * lit) return x;
    }
    return 110.0;
  };
  ShadowEdge edge;
  edge.width_mm = crossing(0.9) - crossing(0.1);
  double umbra = 0;
  for (double x = hidden_mm + 5; x <= hidden_mm + 12; x += 1) umbra += light_at(x) / 8;
  edge.umbra = umbra / lit;
  return edge;
}

// a lamp of some size softens the shadows it casts by how far the occluder is from the floor
// (an edge 2 d tan(radius) wide, d the distance along the light: with 10 degrees and a square
// 40 mm up, 29 mm on the floor at 45 degrees, a 10-90 % width of about 23; 5 mm up, about 3;
// the occluder search makes the far edge a little narrower and the near one a little wider),
// dark in the middle; a point lamp's edge stays within a pixel
TEST(RendererPbrTest, ShadowsOfALampOfSomeSizeSoftenAwayFromTheOccluder) {
  Renderer renderer(320, 240);
  const ShadowEdge hard = ShadowEdgeOf(&renderer, 40, 0);
  const ShadowEdge soft = ShadowEdgeOf(&renderer, 40, 10);
  const ShadowEdge near = ShadowEdgeOf(&renderer, 5, 10);
  EXPECT_LT(hard.width_mm, 2.5);
  EXPECT_GT(soft.width_mm, 11);
  EXPECT_LT(soft.width_mm, 33);
  EXPECT_LT(near.width_mm, 0.5 * soft.width_mm);
  EXPECT_LT(hard.umbra, 0.02);
  EXPECT_LT(soft.umbra, 0.1);
  // the lamp's size is checked
  Light wide;
  wide.radius_rad = 1.f;
  EXPECT_THROW(renderer.Render(CameraLookingDown(300), {wide}, PbrOptions(-1), {}),
               std::runtime_error);
}

// a fixed physically based scene (a procedural hall, two lights, shadows, metal and plastic)
// matches the golden image, shown with a plain clamp and sRGB encoding
TEST(RendererPbrTest, MatchesGoldenImage) {
  Renderer renderer(320, 240);
  const int sphere = renderer.AddMesh(MakeSphere(40, 32, 64));
  const int floor = renderer.AddMesh(testing::MakeSquare(400));
  const int hall = renderer.AddEnvironment(Prefilter(MakeHallEnvironment(3, 128)));
  CameraModel camera = CameraLookingDown(400);
  camera.world_from_camera =
      Eigen::Translation3d(0, -200, 350) * Eigen::AngleAxisd(M_PI + 0.5, Eigen::Vector3d::UnitX());
  Light key;
  key.direction_world = Eigen::Vector3f(0.4f, 0.3f, -1.f).normalized();
  key.diffuse = 0.8f;
  RenderOptions options = PbrOptions(hall, 4);
  options.shadows = true;
  options.environment_intensity = 0.7f;
  DrawItem ground = WhiteItem(floor, 0.f, 0.8f, 0);
  ground.material.color = Eigen::Vector3f(0.25f, 0.35f, 0.6f);
  DrawItem metal = WhiteItem(sphere, 1.f, 0.3f, 1);
  metal.material.color = Eigen::Vector3f(0.9f, 0.9f, 0.92f);
  metal.world_from_object = Eigen::Translation3d(-50, 0, 40) * Eigen::Isometry3d::Identity();
  DrawItem plastic = WhiteItem(sphere, 0.f, 0.4f, 2);
  plastic.material.color = Eigen::Vector3f(0.8f, 0.3f, 0.1f);
  plastic.world_from_object = Eigen::Translation3d(60, 30, 40) * Eigen::Isometry3d::Identity();
  const RenderResult result = renderer.Render(camera, {key}, options, {ground, metal, plastic});
  cv::Mat display(result.color_linear.size(), CV_8UC3);
  for (int v = 0; v < display.rows; ++v) {
    for (int u = 0; u < display.cols; ++u) {
      const cv::Vec3f c = result.color_linear.at<cv::Vec3f>(v, u);
      for (int k = 0; k < 3; ++k) {
        const double x = std::clamp<double>(c[k], 0, 1);
        const double s = x <= 0.0031308 ? 12.92 * x : 1.055 * std::pow(x, 1 / 2.4) - 0.055;
        display.at<cv::Vec3b>(v, u)[2 - k] = static_cast<uint8_t>(std::lround(255 * s));
      }
    }
  }
  testing::ExpectMatchesGolden(display, "render/pbr_golden.png", "render_pbr");
}

}  // namespace
}  // namespace stackgen
