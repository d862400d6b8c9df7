#include "gen/grasp/grasp_scene.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <stdexcept>
#include <string>

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

std::pair<Eigen::Vector3d, Eigen::Vector3d> TangentsOf(const Eigen::Vector3d& n) {
  const Eigen::Vector3d helper =
      std::abs(n.x()) < 0.9 ? Eigen::Vector3d::UnitX() : Eigen::Vector3d::UnitY();
  const Eigen::Vector3d t1 = n.cross(helper).normalized();
  return {t1, n.cross(t1)};
}

struct GraspScene::Impl {
  btDefaultCollisionConfiguration configuration;
  btCollisionDispatcher dispatcher{&configuration};
  btDbvtBroadphase broadphase;
  btCollisionWorld world{&dispatcher, &broadphase, &configuration};
  std::vector<std::unique_ptr<btTriangleMesh>> triangles;
  std::vector<std::unique_ptr<btBvhTriangleMeshShape>> shapes;
  std::vector<std::unique_ptr<btCollisionObject>> objects;
};

GraspScene::GraspScene() : impl_(std::make_unique<Impl>()) {}

GraspScene::~GraspScene() { ClearObjects(); }

int GraspScene::AddMesh(const TriangleMesh& mesh) {
  if (mesh.triangles.empty()) throw std::invalid_argument("GraspScene::AddMesh: no triangles");
  auto triangles = std::make_unique<btTriangleMesh>();
  const size_t count = mesh.positions_mm.size();
  for (const auto& t : mesh.triangles) {
    if (t[0] >= count || t[1] >= count || t[2] >= count) {
      throw std::invalid_argument("GraspScene::AddMesh: a vertex index is out of range");
    }
    triangles->addTriangle(ToBullet(mesh.positions_mm[t[0]].cast<double>()),
                           ToBullet(mesh.positions_mm[t[1]].cast<double>()),
                           ToBullet(mesh.positions_mm[t[2]].cast<double>()));
  }
  impl_->shapes.push_back(std::make_unique<btBvhTriangleMeshShape>(triangles.get(), true));
  impl_->triangles.push_back(std::move(triangles));
  return static_cast<int>(impl_->shapes.size()) - 1;
}

void GraspScene::AddObject(int mesh_id, const Eigen::Isometry3d& world_from_object,
                             int object) {
  if (mesh_id < 0 || mesh_id >= static_cast<int>(impl_->shapes.size())) {
    throw std::invalid_argument("GraspScene::AddObject: unknown mesh id " +
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

void GraspScene::ClearObjects() {
  for (const auto& placed : impl_->objects) impl_->world.removeCollisionObject(placed.get());
  impl_->objects.clear();
}

GraspScene::Hit GraspScene::Cast(const Eigen::Vector3d& from, const Eigen::Vector3d& to,
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

std::vector<SurfacePoint> GraspScene::SeenPoints(const CameraModel& camera,
                                                 const cv::Mat& instance_map, int instance_id,
                                                 int object, int count) const {
  // each chosen pixel's surface, from the camera's ray through its centre
  std::vector<SurfacePoint> points;
  const Eigen::Vector3d origin = camera.world_from_camera.translation();
  for (const cv::Point& p : SpreadOver(instance_map == instance_id, count)) {
    const Eigen::Vector3d ray_camera((p.x - camera.cx) / camera.fx, (p.y - camera.cy) / camera.fy,
                                     1);
    const Eigen::Vector3d to = camera.world_from_camera * (ray_camera * camera.far_mm);
    const Hit seen = Cast(origin, to);
    if (!seen.hit || seen.object != object) continue;
    points.push_back({seen.point, seen.normal, p.x, p.y});
  }
  return points;
}

std::vector<SurfacePoint> GraspScene::PointsFromAbove(int object, int count,
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

  // spread over it as the camera's pixels are
  std::vector<SurfacePoint> points;
  for (const cv::Point& cell : SpreadOver(seen, count)) {
    const Hit& hit = hits[static_cast<size_t>(cell.y * nx + cell.x)];
    points.push_back({hit.point, hit.normal, cell.x, cell.y});
  }
  return points;
}


}  // namespace stackgen
