// Minimal solvers and refinement on random noise-free problems with known
// truth, plus degenerate inputs.
#include <gtest/gtest.h>

#include <cmath>

#include "visloc/pose/pose_refinement.h"
#include "visloc/util/random.h"
#include "visloc/pose/solvers/dlt6.h"
#include "visloc/pose/solvers/p3p.h"

namespace visloc {
namespace {

Eigen::Matrix3d random_rotation(RandomGenerator& rng) {
  return Eigen::Quaterniond(rng.normal(), rng.normal(), rng.normal(), rng.normal()).normalized().toRotationMatrix();
}

// Random camera and n world points in front of it (depth 2..10, within ±45°).
struct Problem {
  Eigen::Matrix3d R;
  Eigen::Vector3d t;
  std::vector<Eigen::Vector3d> world;
  std::vector<Eigen::Vector3d> cam;
};
Problem random_problem(RandomGenerator& rng, int n) {
  Problem p;
  p.R = random_rotation(rng);
  p.t = Eigen::Vector3d(rng.uniform(-5, 5), rng.uniform(-5, 5), rng.uniform(-5, 5));
  for (int i = 0; i < n; ++i) {
    const double z = rng.uniform(2, 10);
    const Eigen::Vector3d c(rng.uniform(-1, 1) * z, rng.uniform(-1, 1) * z, z);
    p.cam.push_back(c);
    p.world.push_back(p.R.transpose() * (c - p.t));
  }
  return p;
}

TEST(Cubic, KnownRoots) {
  double r[3];
  // (x−1)(x−2)(x+3) = x³ − 7x + 6
  ASSERT_EQ(solve_cubic_real(1, 0, -7, 6, r), 3);
  std::sort(r, r + 3);
  EXPECT_NEAR(r[0], -3, 1e-12);
  EXPECT_NEAR(r[1], 1, 1e-12);
  EXPECT_NEAR(r[2], 2, 1e-12);
  // x³ + x + 1 has one real root ≈ −0.6823278
  ASSERT_EQ(solve_cubic_real(2, 0, 2, 2, r), 1);
  EXPECT_NEAR(r[0], -0.6823278038280193, 1e-12);
  // Degree drop: 2x² − 8 = 0
  ASSERT_EQ(solve_cubic_real(0, 2, 0, -8, r), 2);
  EXPECT_NEAR(std::abs(r[0]), 2, 1e-12);
  EXPECT_NEAR(std::abs(r[1]), 2, 1e-12);
  EXPECT_EQ(solve_cubic_real(0, 0, 0, 0, r), 0);
}

TEST(P3P, RecoversRandomPosesExactly) {
  RandomGenerator rng(1);
  int recovered = 0, total = 2000, worse_than_1e6 = 0;
  for (int trial = 0; trial < total; ++trial) {
    Problem p = random_problem(rng, 3);
    std::array<Eigen::Vector3d, 3> bearings, points;
    for (int i = 0; i < 3; ++i) {
      bearings[i] = p.cam[i].normalized();
      points[i] = p.world[i];
    }
    std::array<Matrix34d, 4> sols;
    const int ns = solve_p3p(bearings, points, &sols);
    ASSERT_LE(ns, 4);
    double best = 1e9;
    for (int k = 0; k < ns; ++k) {
      const double e = (sols[k].leftCols<3>() - p.R).norm() + (sols[k].col(3) - p.t).norm();
      best = std::min(best, e);
      // Every solution reprojects the three points exactly.
      for (int i = 0; i < 3; ++i) {
        const Eigen::Vector3d c = sols[k].leftCols<3>() * points[i] + sols[k].col(3);
        EXPECT_GT(c.z(), 0);
        EXPECT_LT((c.normalized() - bearings[i]).norm(), 1e-6);
      }
    }
    if (best < 1e-6) ++recovered;
    if (best >= 1e-6) ++worse_than_1e6;
  }
  // Random triangles include a few near-degenerate ones (near the danger
  // cylinder); the true pose must be found to 1e-6 in nearly all.
  EXPECT_GE(recovered, total * 995 / 1000) << worse_than_1e6 << " trials above 1e-6";
}

TEST(P3P, DegenerateInputsGiveNoSolution) {
  std::array<Matrix34d, 4> sols;
  std::array<Eigen::Vector3d, 3> bearings{Eigen::Vector3d(0, 0, 1), Eigen::Vector3d(0.1, 0, 1),
                                          Eigen::Vector3d(0, 0.1, 1)};
  // Collinear world points.
  std::array<Eigen::Vector3d, 3> collinear{Eigen::Vector3d(0, 0, 5), Eigen::Vector3d(1, 0, 5),
                                           Eigen::Vector3d(2, 0, 5)};
  EXPECT_EQ(solve_p3p(bearings, collinear, &sols), 0);
  // Coincident world points.
  std::array<Eigen::Vector3d, 3> same{Eigen::Vector3d(1, 2, 3), Eigen::Vector3d(1, 2, 3), Eigen::Vector3d(0, 0, 5)};
  EXPECT_EQ(solve_p3p(bearings, same, &sols), 0);
  // Identical rays.
  std::array<Eigen::Vector3d, 3> rays{Eigen::Vector3d(0, 0, 1), Eigen::Vector3d(0, 0, 2), Eigen::Vector3d(0, 0.1, 1)};
  std::array<Eigen::Vector3d, 3> pts{Eigen::Vector3d(0, 0, 5), Eigen::Vector3d(1, 0, 5), Eigen::Vector3d(0, 1, 5)};
  EXPECT_EQ(solve_p3p(rays, pts, &sols), 0);
  // Zero ray.
  std::array<Eigen::Vector3d, 3> zero{Eigen::Vector3d(0, 0, 0), Eigen::Vector3d(0.1, 0, 1), Eigen::Vector3d(0, 0.1, 1)};
  EXPECT_EQ(solve_p3p(zero, pts, &sols), 0);
}

TEST(DLT, RecoversProjectionAndDecomposition) {
  RandomGenerator rng(2);
  int recovered = 0;
  const int total = 500;
  for (int trial = 0; trial < total; ++trial) {
    Problem p = random_problem(rng, 6);
    const double f = rng.uniform(300, 3000);
    std::vector<Eigen::Vector2d> x;
    for (const auto& c : p.cam) x.emplace_back(f * c.x() / c.z(), f * c.y() / c.z());
    Matrix34d P;
    ASSERT_TRUE(solve_dlt(x.data(), p.world.data(), 6, &P));
    DecomposedProjection d;
    ASSERT_TRUE(decompose_projection(P, &d));
    const double e = std::abs(d.focal - f) / f + (d.rotation - p.R).norm() + (d.translation - p.t).norm() / 10;
    if (e < 1e-6) ++recovered;
    // Reprojection of the six points.
    for (int i = 0; i < 6; ++i) {
      const Eigen::Vector3d q = P * p.world[i].homogeneous();
      EXPECT_GT(q.z(), 0);
      EXPECT_LT((q.head<2>() / q.z() - x[i]).norm(), 1e-6 * f);
    }
  }
  EXPECT_GE(recovered, total * 99 / 100);
}

TEST(DLT, ManyPointsWithNoiseAreClose) {
  RandomGenerator rng(3);
  Problem p = random_problem(rng, 200);
  const double f = 1000;
  std::vector<Eigen::Vector2d> x;
  for (const auto& c : p.cam) x.emplace_back(f * c.x() / c.z() + rng.normal(), f * c.y() / c.z() + rng.normal());
  Matrix34d P;
  ASSERT_TRUE(solve_dlt(x.data(), p.world.data(), 200, &P));
  DecomposedProjection d;
  ASSERT_TRUE(decompose_projection(P, &d));
  EXPECT_NEAR(d.focal, f, 0.02 * f);
  EXPECT_LT((d.rotation - p.R).norm(), 0.02);
}

TEST(DLT, DegenerateInputs) {
  Matrix34d P;
  std::vector<Eigen::Vector2d> x(6, Eigen::Vector2d(1, 2));
  std::vector<Eigen::Vector3d> X;
  for (int i = 0; i < 6; ++i) X.emplace_back(i, (i * 7) % 5, 10);  // coplanar (z = 10)
  for (int i = 0; i < 6; ++i) x[i] = Eigen::Vector2d(X[i].x() * 100, X[i].y() * 100);
  EXPECT_FALSE(solve_dlt(x.data(), X.data(), 6, &P));
  EXPECT_FALSE(solve_dlt(x.data(), X.data(), 5, &P));
  std::vector<Eigen::Vector3d> same(6, Eigen::Vector3d(1, 1, 1));
  EXPECT_FALSE(solve_dlt(x.data(), same.data(), 6, &P));
  DecomposedProjection d;
  EXPECT_FALSE(decompose_projection(Matrix34d::Zero(), &d));
}

TEST(Refinement, ConvergesFromPerturbedPoseWithFocal) {
  RandomGenerator rng(4);
  Problem p = random_problem(rng, 100);
  const double f = 800;
  std::vector<Eigen::Vector2d> x;
  for (const auto& c : p.cam) x.emplace_back(f * c.x() / c.z(), f * c.y() / c.z());
  // 20% gross outliers: the Cauchy loss must keep them from biasing the pose.
  for (int i = 0; i < 20; ++i) x[i] += Eigen::Vector2d(rng.uniform(-200, 200), rng.uniform(-200, 200));
  const CameraPose truth = CameraPose::from_matrix(p.R, p.t);
  CameraPose init = truth;
  init.rotation = (init.rotation * Eigen::Quaterniond(Eigen::AngleAxisd(0.03, Eigen::Vector3d(1, 2, 3).normalized())))
                      .normalized();
  init.translation += Eigen::Vector3d(0.1, -0.1, 0.2);
  RefinementOptions o;
  o.refine_focal = true;
  o.max_iterations = 100;
  RefinementResult r = refine_pose(x.data(), p.world.data(), x.size(), init, 0.9 * f, o);
  ASSERT_TRUE(r.success);
  EXPECT_LT(r.final_cost, r.initial_cost);
  // The Cauchy loss leaves a small bias from the outliers, not their full pull.
  EXPECT_LT(rotation_error_deg(r.cam_from_world, truth), 1e-2);
  EXPECT_LT(position_error(r.cam_from_world, truth), 1e-2);
  EXPECT_NEAR(r.focal, f, 0.5);

  // Noise-free inliers only, fixed focal: recovers the truth to 1e-6.
  RefinementOptions fixed;
  fixed.max_iterations = 100;
  r = refine_pose(x.data() + 20, p.world.data() + 20, 80, init, f, fixed);
  ASSERT_TRUE(r.success);
  EXPECT_LT(rotation_error_deg(r.cam_from_world, truth), 1e-6);
  EXPECT_LT(position_error(r.cam_from_world, truth), 1e-6);
  EXPECT_EQ(r.focal, f);
}

TEST(Refinement, ValidatesOptions) {
  RefinementOptions o;
  o.loss_scale_px = 0;
  EXPECT_THROW(o.validate(), std::exception);
}

}  // namespace
}  // namespace visloc
