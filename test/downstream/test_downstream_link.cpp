// A user's package can build on endo_stereo: the minimal catkin package in
// test/downstream/endo_stereo_downstream_check is configured against this build's devel space
// (find_package(catkin REQUIRED COMPONENTS endo_stereo): the exported include directories and
// libraries), built, and run; it matches a generated pair and checks the result.
#include <gtest/gtest.h>
#include <sys/wait.h>

#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <sstream>
#include <string>

namespace {

/// Runs @p cmd with its output in @p log; returns the exit status (-1 when it did not run). The
/// system Python comes first on PATH: catkin's and ament's CMake steps need its ROS modules, as
/// for the main build (scripts/env.sh).
int run(const std::string& cmd, const std::string& log) {
  const std::string line = "PATH=/usr/bin:$PATH " + cmd + " > '" + log + "' 2>&1";
  const int rc = std::system(line.c_str());
  return WIFEXITED(rc) ? WEXITSTATUS(rc) : -1;
}

std::string tail(const std::string& path, size_t max_chars = 4000) {
  std::ifstream f(path);
  std::stringstream ss;
  ss << f.rdbuf();
  const std::string s = ss.str();
  return s.size() > max_chars ? s.substr(s.size() - max_chars) : s;
}

TEST(DownstreamPackage, FindsLinksAndRunsTheCore) {
  const std::string src =
      std::string(ES_SOURCE_DIR) + "/test/downstream/endo_stereo_downstream_check";
  const std::string build = std::string(ES_BINARY_DIR) + "/downstream_check";
  ASSERT_EQ(run("rm -rf '" + build + "' && mkdir -p '" + build + "'", "/dev/null"), 0);
  const std::string configure_log = build + "/configure.log";
  // The devel space of this build is the only place endo_stereo is found (no installed copy).
  const int configured =
      run("cmake -S '" + src + "' -B '" + build + "/build' -DCMAKE_PREFIX_PATH='" +
              ES_DEVEL_PREFIX + "' -DCATKIN_DEVEL_PREFIX='" + build +
              "/devel' -DPYTHON_EXECUTABLE=/usr/bin/python3 -DPython3_EXECUTABLE=/usr/bin/python3 "
              "-DCATKIN_ENABLE_TESTING=OFF",
          configure_log);
  ASSERT_EQ(configured, 0) << "configuring the downstream package failed:\n" << tail(configure_log);
  const std::string build_log = build + "/build.log";
  ASSERT_EQ(run("cmake --build '" + build + "/build' -j2", build_log), 0)
      << "building the downstream package failed:\n"
      << tail(build_log);
  const std::string run_log = build + "/run.log";
  const int rc =
      run("'" + build + "/devel/lib/endo_stereo_downstream_check/downstream_match'", run_log);
  EXPECT_EQ(rc, 0) << tail(run_log);
  std::printf("%s", tail(run_log).c_str());
}

}  // namespace

int main(int argc, char** argv) {
  ::testing::InitGoogleTest(&argc, argv);
  return RUN_ALL_TESTS();
}
