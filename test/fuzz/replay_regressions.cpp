// Replays the inputs that once crashed a fuzz harness (test/fuzz/regressions/<harness>) through
// that harness, as `make test` runs it (plain and under ASan+UBSan). The harness is linked in
// unchanged: each input runs through its LLVMFuzzerTestOneInput, whose contract checks abort on a
// violation, so a regression is a crash (a non-zero exit, which the test runner fails by name) or
// a sanitizer report; the file being replayed is printed first, so the log names it.
#include <gtest/gtest.h>

#include <algorithm>
#include <cstdint>
#include <cstdio>
#include <dirent.h>
#include <fstream>
#include <iterator>
#include <string>
#include <vector>

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size);

namespace {

std::vector<std::string> listFiles(const std::string& dir) {
  std::vector<std::string> files;
  if (DIR* d = ::opendir(dir.c_str())) {
    while (const dirent* e = ::readdir(d)) {
      const std::string name = e->d_name;
      if (name != "." && name != "..") files.push_back(dir + "/" + name);
    }
    ::closedir(d);
  }
  std::sort(files.begin(), files.end());
  return files;
}

TEST(FuzzRegressions, EveryRecordedInputRunsWithinTheContract) {
  const std::vector<std::string> files = listFiles(ES_FUZZ_REGRESSIONS_DIR);
  // The folder is in the repository: an empty list means the path is wrong, not that all passed.
  ASSERT_FALSE(files.empty()) << "no regression inputs in " << ES_FUZZ_REGRESSIONS_DIR;
  for (const std::string& path : files) {
    std::fprintf(stderr, "replaying %s\n", path.c_str());
    std::ifstream in(path, std::ios::binary);
    ASSERT_TRUE(in.good()) << path;
    const std::vector<uint8_t> bytes((std::istreambuf_iterator<char>(in)),
                                     std::istreambuf_iterator<char>());
    EXPECT_EQ(LLVMFuzzerTestOneInput(bytes.data(), bytes.size()), 0) << path;
  }
}

}  // namespace

int main(int argc, char** argv) {
  ::testing::InitGoogleTest(&argc, argv);
  return RUN_ALL_TESTS();
}
