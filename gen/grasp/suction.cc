#include "gen/grasp/suction.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <stdexcept>
#include <string>
#include <tuple>

#include <btBulletCollisionCommon.h>
#include <opencv2/imgproc.hpp>

namespace stackgen {

namespace {

btVector3 ToBullet(const Eigen::Vector3d& v) {
  return btVector3(static_cast<btScalar>(v.x()), static_cast<btScalar>(v.y()),
                   static_cast<btScalar>(v.z()));
}

Eigen::Vector3d FromBullet(const btVector3& v) { return Eigen::Vector3d(v.x(), v.y(), v.z()); }

// the closest hit, of one object only when `only` >= 0
struct ClosestOf : btCollisionWorld::ClosestRayResultCallback {
  ClosestOf(const btVector3& from, const btVector3& to, int only)
      : btCollisionWorld::ClosestRayResultCallback(from, to), only_object(only) {}
  bool needsCollision(btBroadphaseProxy* proxy) const override {
    if (only_object >= 0) {
      const auto* object = static_cast<const btCollisionObject*>(proxy->m_clientObject);
      if (object->getUserIndex() != only_object) return false;
    }
    return btCollisionWorld::ClosestRayResultCallback::needsCollision(proxy);
  }
  int only_object;
};

// two unit vectors that make a right-handed frame with the unit `n`
std::pair<Eigen::Vector3d, Eigen::Vector3d> TangentsOf(const Eigen::Vector3d& n) {
  const Eigen::Vector3d helper =
      std::abs(n.x()) < 0.9 ? Eigen::Vector3d::UnitX() : Eigen::Vector3d::UnitY();
  const Eigen::Vector3d t1 = n.cross(helper).normalized();
  return {t1, n.cross(t1)};
}

// up to `count` pixels spread over the nonzero pixels of `mask`: farthest point sampling over
// the inner half of the region (by distance to its edge), from its deepest pixel
std::vector<cv::Point> SpreadOver(const cv::Mat& mask, int count) {
  std::vector<cv::Point> pixels;
  cv::findNonZero(mask, pixels);
  if (pixels.empty()) return {};
  cv::Mat inside;
  cv::distanceTransform(mask, inside, cv::DIST_L2, 3);
  double deepest = 0;
  cv::minMaxLoc(inside, nullptr, &deepest);

  // farthest point sampling over the inner half of the region, from its deepest pixel
  std::vector<cv::Point> pool;
  cv::Point first = pixels[0];
  float first_depth = -1;
  for (const cv::Point& p : pixels) {
    const float d = inside.at<float>(p);
    if (d >= 0.5 * deepest) pool.push_back(p);
    if (d > first_depth) {
      first_depth = d;
      first = p;
    }
  }
  std::vector<cv::Point> chosen = {first};
  std::vector<double> nearest(pool.size(), std::numeric_limits<double>::infinity());
  while (static_cast<int>(chosen.size()) < count) {
    const cv::Point last = chosen.back();
    size_t best = 0;
    double best_distance = -1;
    for (size_t i = 0; i < pool.size(); ++i) {
      const double dx = pool[i].x - last.x, dy = pool[i].y - last.y;
      nearest[i] = std::min(nearest[i], dx * dx + dy * dy);
      if (nearest[i] > best_distance) {
        best_distance = nearest[i];
        best = i;
      }
    }
    if (best_distance <= 0) break;
    chosen.push_back(pool[best]);
  }
  return chosen;
}

}  // namespace

bool BetterSuction(const SuctionGrasp& a, const SuctionGrasp& b) {
  return std::make_tuple(!a.approach_clear, -a.seal, a.com_offset_mm, a.v, a.u) <
         std::make_tuple(!b.approach_clear, -b.seal, b.com_offset_mm, b.v, b.u);
}

struct SuctionScene::Impl {
  btDefaultCollisionConfiguration configuration;
  btCollisionDispatcher dispatcher{&configuration};
  btDbvtBroadphase broadphase;
  btCollisionWorld world{&dispatcher, &broadphase, &configuration};
  std::vector<std::unique_ptr<btTriangleMesh>> triangles;
  std::vector<std::unique_ptr<btBvhTriangleMeshShape>> shapes;
  std::vector<std::unique_ptr<btCollisionObject>> objects;
};

SuctionScene::SuctionScene() : impl_(std::make_unique<Impl>()) {}

SuctionScene::~SuctionScene() { ClearObjects(); }

int SuctionScene::AddMesh(const TriangleMesh& mesh) {
  if (mesh.triangles.empty()) throw std::invalid_argument("SuctionScene::AddMesh: no triangles");
  auto triangles = std::make_unique<btTriangleMesh>();
  const size_t count = mesh.positions_mm.size();
  for (const auto& t : mesh.triangles) {
    if (t[0] >= count || t[1] >= count || t[2] >= count) {
      throw std::invalid_argument("SuctionScene::AddMesh: a vertex index is out of range");
    }
    triangles->addTriangle(ToBullet(mesh.positions_mm[t[0]].cast<double>()),
                           ToBullet(mesh.positions_mm[t[1]].cast<double>()),
                           ToBullet(mesh.positions_mm[t[2]].cast<double>()));
  }
  impl_->shapes.push_back(std::make_unique<btBvhTriangleMeshShape>(triangles.get(), true));
  impl_->triangles.push_back(std::move(triangles));
  return static_cast<int>(impl_->shapes.size()) - 1;
}

void SuctionScene::AddObject(int mesh_id, const Eigen::Isometry3d& world_from_object,
                             int object) {
  if (mesh_id < 0 || mesh_id >= static_cast<int>(impl_->shapes.size())) {
    throw std::invalid_argument("SuctionScene::AddObject: unknown mesh id " +
                                std::to_string(mesh_id));
  }
  auto placed = std::make_unique<btCollisionObject>();
  placed->setCollisionShape(impl_->shapes[static_cast<size_t>(mesh_id)].get());
  btTransform transform;
  transform.setOrigin(ToBullet(world_from_object.translation()));
  const Eigen::Matrix3d r = world_from_object.linear();
  transform.setBasis(btMatrix3x3(
      static_cast<btScalar>(r(0, 0)), static_cast<btScalar>(r(0, 1)),
      static_cast<btScalar>(r(0, 2)), static_cast<btScalar>(r(1, 0)),
      static_cast<btScalar>(r(1, 1)), static_cast<btScalar>(r(1, 2)),
      static_cast<btScalar>(r(2, 0)), static_cast<btScalar>(r(2, 1)),
      static_cast<btScalar>(r(2, 2))));
  placed->setWorldTransform(transform);
  placed->setUserIndex(object);
  impl_->world.addCollisionObject(placed.get());
  impl_->objects.push_back(std::move(placed));
}

void SuctionScene::ClearObjects() {
  for (const auto& placed : impl_->objects) impl_->world.removeCollisionObject(placed.get());
  impl_->objects.clear();
}

SuctionScene::Hit SuctionScene::Cast(const Eigen::Vector3d& from, const Eigen::Vector3d& to,
                                     int only_object) const {
  ClosestOf closest(ToBullet(from), ToBullet(to), only_object);
  impl_->world.rayTest(closest.m_rayFromWorld, closest.m_rayToWorld, closest);
  Hit hit;
  if (!closest.hasHit()) return hit;
  hit.hit = true;
  hit.point = FromBullet(closest.m_hitPointWorld);
  hit.normal = FromBullet(closest.m_hitNormalWorld).normalized();
  // (a triangle mesh's normal faces the ray's start)
  if (hit.normal.dot(from - hit.point) < 0) hit.normal = -hit.normal;
  hit.object = closest.m_collisionObject->getUserIndex();
  hit.distance_mm = closest.m_closestHitFraction * (to - from).norm();
  return hit;
}

SuctionGrasp SuctionScene::Evaluate(const Eigen::Vector3d& point, const Eigen::Vector3d& normal,
                                    int object, const Eigen::Vector3d& com_world,
                                    const SuctionCup& cup) const {
  SuctionGrasp grasp;
  grasp.point_mm = point;
  grasp.normal = normal.normalized();
  const Eigen::Vector3d& n = grasp.normal;
  const auto [t1, t2] = TangentsOf(n);

  // the seal: the part's surface under the cup's disc (centre, half radius, lip) within the
  // lip's compliance of the tangent plane, each point looked for from above
  const double radius = cup.diameter_mm / 2;
  const double reach = cup.compliance_mm + 5;
  int sealed = 0, samples = 0;
  for (const auto& [ring_radius, count] : {std::pair<double, int>{0, 1}, {radius / 2, 8},
                                           {radius, 16}}) {
    for (int k = 0; k < count; ++k) {
      const double angle = 2 * M_PI * k / count;
      const Eigen::Vector3d q =
          point + ring_radius * (std::cos(angle) * t1 + std::sin(angle) * t2);
      const Hit below = Cast(q + reach * n, q - reach * n, object);
      ++samples;
      if (below.hit && std::abs((below.point - point).dot(n)) <= cup.compliance_mm) ++sealed;
    }
  }
  grasp.seal = static_cast<double>(sealed) / samples;

  // the approach: the tool's cylinder (its axis and 16 lines on its side) out along the normal,
  // from just above the lip's compliance, against everything
  const double start = cup.compliance_mm + 1;
  double clearance = cup.approach_mm;
  const double tool_radius = std::max(cup.tool_diameter_mm, cup.diameter_mm) / 2;
  for (int k = -1; k < 16; ++k) {
    const double angle = 2 * M_PI * k / 16;
    const Eigen::Vector3d q =
        point + start * n +
        (k < 0 ? Eigen::Vector3d::Zero()
               : Eigen::Vector3d(tool_radius * (std::cos(angle) * t1 + std::sin(angle) * t2)));
    const Hit out = Cast(q, q + (cup.approach_mm - start) * n);
    if (out.hit) clearance = std::min(clearance, start + out.distance_mm);
  }
  grasp.clearance_mm = clearance;
  grasp.approach_clear = clearance >= cup.approach_mm;
  const Eigen::Vector3d lever = com_world - point;
  grasp.com_offset_mm = (lever - lever.dot(n) * n).norm();
  return grasp;
}

std::vector<SuctionGrasp> SuctionScene::Candidates(const CameraModel& camera,
                                                   const cv::Mat& instance_map, int instance_id,
                                                   int object, const Eigen::Vector3d& com_world,
                                                   const SuctionCup& cup) const {
  const std::vector<cv::Point> chosen =
      SpreadOver(instance_map == instance_id, cup.candidates_per_part);

  // each pixel's surface, from the camera's ray through its centre, evaluated
  std::vector<SuctionGrasp> grasps;
  const Eigen::Vector3d origin = camera.world_from_camera.translation();
  for (const cv::Point& p : chosen) {
    const Eigen::Vector3d ray_camera((p.x - camera.cx) / camera.fx, (p.y - camera.cy) / camera.fy,
                                     1);
    const Eigen::Vector3d to = camera.world_from_camera * (ray_camera * camera.far_mm);
    const Hit seen = Cast(origin, to);
    if (!seen.hit || seen.object != object) continue;
    SuctionGrasp grasp = Evaluate(seen.point, seen.normal, object, com_world, cup);
    grasp.u = p.x;
    grasp.v = p.y;
    grasps.push_back(grasp);
  }
  std::sort(grasps.begin(), grasps.end(), BetterSuction);
  return grasps;
}

std::vector<SuctionGrasp> SuctionScene::CandidatesFromAbove(int object,
                                                            const Eigen::Vector3d& com_world,
                                                            const SuctionCup& cup,
                                                            double pitch_mm) const {
  // the object's box, and the top of everything
  const btCollisionObject* placed = nullptr;
  btVector3 top_low, top_high(0, 0, -BT_LARGE_FLOAT);
  for (const auto& candidate : impl_->objects) {
    btVector3 low, high;
    candidate->getCollisionShape()->getAabb(candidate->getWorldTransform(), low, high);
    top_high.setZ(std::max(top_high.z(), high.z()));
    if (candidate->getUserIndex() == object) placed = candidate.get();
  }
  if (placed == nullptr || !(pitch_mm > 0)) return {};
  btVector3 low, high;
  placed->getCollisionShape()->getAabb(placed->getWorldTransform(), low, high);
  const int nx = static_cast<int>(std::ceil((high.x() - low.x()) / pitch_mm)) + 1;
  const int ny = static_cast<int>(std::ceil((high.y() - low.y()) / pitch_mm)) + 1;

  // straight down on a grid over it: where the object is what a ray meets first
  cv::Mat seen(ny, nx, CV_8UC1, cv::Scalar(0));
  std::vector<Hit> hits(static_cast<size_t>(nx * ny));
  for (int iy = 0; iy < ny; ++iy) {
    for (int ix = 0; ix < nx; ++ix) {
      const Eigen::Vector3d from(low.x() + ix * pitch_mm, low.y() + iy * pitch_mm,
                                 top_high.z() + 10);
      const Hit hit = Cast(from, Eigen::Vector3d(from.x(), from.y(), low.z() - 1));
      if (!hit.hit || hit.object != object) continue;
      seen.at<uint8_t>(iy, ix) = 255;
      hits[static_cast<size_t>(iy * nx + ix)] = hit;
    }
  }

  // spread over it as the camera's candidates are, evaluated, best first
  std::vector<SuctionGrasp> grasps;
  for (const cv::Point& cell : SpreadOver(seen, cup.candidates_per_part)) {
    const Hit& hit = hits[static_cast<size_t>(cell.y * nx + cell.x)];
    SuctionGrasp grasp = Evaluate(hit.point, hit.normal, object, com_world, cup);
    grasp.u = cell.x;
    grasp.v = cell.y;
    grasps.push_back(grasp);
  }
  std::sort(grasps.begin(), grasps.end(), BetterSuction);
  return grasps;
}

}  // namespace stackgen
