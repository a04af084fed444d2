// JumpMap::apply must not touch the heap. This binary replaces the global operator new and,
// linked with -Wl,--wrap=malloc,calloc,realloc, sees the direct malloc calls Eigen makes in
// the statically linked core library too; it counts both while a test asks it to.
#include <atomic>
#include <cstdlib>
#include <new>
#include <random>

#include <gtest/gtest.h>

#include "bflow/core/jump_map.h"
#include "support/random_jump.h"

namespace {
std::atomic<bool> counting{false};
std::atomic<long> allocations{0};
}  // namespace

extern "C" {
void* __real_malloc(std::size_t size);
void* __real_calloc(std::size_t count, std::size_t size);
void* __real_realloc(void* p, std::size_t size);
void* __wrap_malloc(std::size_t size) {
  if (counting.load(std::memory_order_relaxed)) allocations.fetch_add(1);
  return __real_malloc(size);
}
void* __wrap_calloc(std::size_t count, std::size_t size) {
  if (counting.load(std::memory_order_relaxed)) allocations.fetch_add(1);
  return __real_calloc(count, size);
}
void* __wrap_realloc(void* p, std::size_t size) {
  if (counting.load(std::memory_order_relaxed)) allocations.fetch_add(1);
  return __real_realloc(p, size);
}
}

void* operator new(std::size_t size) {
  if (counting.load(std::memory_order_relaxed)) allocations.fetch_add(1);
  if (void* p = std::malloc(size == 0 ? 1 : size)) return p;
  throw std::bad_alloc();
}
void* operator new[](std::size_t size) { return operator new(size); }
void operator delete(void* p) noexcept { std::free(p); }
void operator delete[](void* p) noexcept { std::free(p); }
void operator delete(void* p, std::size_t) noexcept { std::free(p); }
void operator delete[](void* p, std::size_t) noexcept { std::free(p); }

namespace bflow {
namespace {

// Counts the allocations made by `f`.
template <typename F>
long allocations_during(F&& f) {
  allocations = 0;
  counting = true;
  f();
  counting = false;
  return allocations.load();
}

TEST(JumpMapAllocationTest, CountingSeesAllocationsInsideTheLibrary) {
  // The counter must see an allocation, or the zeros below would prove nothing: the
  // value-returning apply() allocates its result inside the core library through Eigen.
  const JumpMap jump(Eigen::MatrixXd::Identity(2, 2), Eigen::MatrixXd::Ones(2, 4));
  const Eigen::VectorXd dx = Eigen::Vector2d(0.5, -0.25);
  Eigen::VectorXd image;
  EXPECT_GE(allocations_during([&] { image = jump.apply(dx); }), 1);
  EXPECT_EQ(image, dx);  // all limits equal: B is the identity
  EXPECT_GE(allocations_during([&] { image = jump.order(dx).times.size() * dx; }), 1);
}

TEST(JumpMapAllocationTest, ApplyWithATableAllocatesNothing) {
  std::mt19937_64 rng(11);
  for (int n : {1, 3, 8}) {
    const int d = n + 5;
    const Eigen::MatrixXd eta = testing::random_normals(rng, n, d, false);
    const JumpMap jump(eta, testing::random_limits(rng, eta, {}));
    const Eigen::MatrixXd tangents = Eigen::MatrixXd::Random(d, 50);
    Eigen::VectorXd out(d);
    Eigen::MatrixXd block(d, 50);
    EXPECT_EQ(allocations_during([&] {
                for (Eigen::Index k = 0; k < tangents.cols(); ++k) jump.apply(tangents.col(k), out);
                jump.apply_block(tangents, block);
              }),
              0)
        << "n=" << n;
  }
}

TEST(JumpMapAllocationTest, ApplyWithALazySourceAllocatesNothingEvenWhenTheCacheRefills) {
  std::mt19937_64 rng(12);
  for (int n : {6, 64}) {
    const int d = n == 64 ? 256 : 10;
    const Eigen::MatrixXd eta = testing::random_normals(rng, n, d, false);
    // The smallest cache is cleared after every apply(): every word is evaluated afresh.
    const JumpMap jump(eta, testing::HashedLimits(rng, eta), JumpMapOptions{n + 1});
    const Eigen::MatrixXd tangents = Eigen::MatrixXd::Random(d, 20);
    Eigen::VectorXd out(d);
    EXPECT_EQ(allocations_during([&] {
                for (Eigen::Index k = 0; k < tangents.cols(); ++k) jump.apply(tangents.col(k), out);
              }),
              0)
        << "n=" << n;
  }
}

}  // namespace
}  // namespace bflow
