// The tools' shared pieces: argument reading (a bad number is an error naming the flag and the
// text) and the image-file frame source (patterns, first index, counts, errors).
#include <gtest/gtest.h>
#include <unistd.h>

#include <climits>
#include <cstdlib>
#include <opencv2/imgcodecs.hpp>
#include <string>
#include <vector>

#include "frame_sources.hpp"
#include "tool_args.hpp"

namespace {

using endo_stereo::tools::ArgReader;
using endo_stereo::tools::UsageError;

TEST(ParseInt, TakesWholeBaseTenIntegersOnly) {
  int v = 0;
  EXPECT_TRUE(endo_stereo::tools::parseInt("12", &v));
  EXPECT_EQ(v, 12);
  EXPECT_TRUE(endo_stereo::tools::parseInt("-3", &v));
  EXPECT_EQ(v, -3);
  EXPECT_TRUE(endo_stereo::tools::parseInt("+4", &v));
  EXPECT_EQ(v, 4);
  EXPECT_TRUE(endo_stereo::tools::parseInt("2147483647", &v));
  EXPECT_EQ(v, INT_MAX);
  EXPECT_TRUE(endo_stereo::tools::parseInt("-2147483648", &v));
  EXPECT_EQ(v, INT_MIN);
  v = 7;
  for (const char* bad : {"", "abc", "1x", "1e3", "1e99", "1.0", " 5", "5 ", "0x10", "2147483648",
                          "-2147483649", "99999999999999999999"}) {
    EXPECT_FALSE(endo_stereo::tools::parseInt(bad, &v)) << "'" << bad << "'";
    EXPECT_EQ(v, 7) << "'" << bad << "' changed the output";
  }
}

TEST(ParseInt, SixtyFourBitVariant) {
  int64_t v = 0;
  EXPECT_TRUE(endo_stereo::tools::parseInt64("4294967295", &v));
  EXPECT_EQ(v, 4294967295LL);
  EXPECT_FALSE(endo_stereo::tools::parseInt64("99999999999999999999", &v));
  EXPECT_FALSE(endo_stereo::tools::parseInt64("12abc", &v));
}

TEST(ParseDouble, TakesWholeFiniteNumbersOnly) {
  double v = 0;
  EXPECT_TRUE(endo_stereo::tools::parseDouble("0.5", &v));
  EXPECT_EQ(v, 0.5);
  EXPECT_TRUE(endo_stereo::tools::parseDouble("-2", &v));
  EXPECT_EQ(v, -2.0);
  EXPECT_TRUE(endo_stereo::tools::parseDouble("1e-3", &v));
  EXPECT_EQ(v, 1e-3);
  v = 7;
  for (const char* bad : {"", "abc", "1.5x", "nan", "inf", "-inf", "1e999", " 1", "1,5"}) {
    EXPECT_FALSE(endo_stereo::tools::parseDouble(bad, &v)) << "'" << bad << "'";
    EXPECT_EQ(v, 7) << "'" << bad << "' changed the output";
  }
}

TEST(SplitList, DropsEmptyItems) {
  EXPECT_EQ(endo_stereo::tools::splitList("a,,b,", ','), (std::vector<std::string>{"a", "b"}));
  EXPECT_TRUE(endo_stereo::tools::splitList("", ',').empty());
  EXPECT_EQ(endo_stereo::tools::splitList("640x480", 'x'),
            (std::vector<std::string>{"640", "480"}));
}

// Runs a reader over @p words (argv[0] = "tool") and returns what the callback made of them.
struct Argv {
  explicit Argv(std::vector<std::string> words) : storage(std::move(words)) {
    storage.insert(storage.begin(), "tool");
    for (std::string& w : storage) pointers.push_back(&w[0]);
  }
  int argc() const { return static_cast<int>(pointers.size()); }
  char** argv() { return pointers.data(); }
  std::vector<std::string> storage;
  std::vector<char*> pointers;
};

// The message of the UsageError that @p read throws on "FLAG VALUE" ("" when none is thrown).
template <typename Read>
std::string errorOf(const std::string& flag, const std::string& value, Read read) {
  Argv a({flag, value});
  ArgReader args(a.argc(), a.argv());
  try {
    EXPECT_TRUE(args.next());
    read(args);
  } catch (const UsageError& e) {
    return e.what();
  }
  return "";
}

TEST(ArgReader, ReadsFlagsAndValuesInOrder) {
  Argv a({"--name", "x", "--count", "3", "--scale", "0.25", "--quiet", "--seed", "4294967295"});
  ArgReader args(a.argc(), a.argv());
  ASSERT_TRUE(args.next());
  EXPECT_TRUE(args.is("--name"));
  EXPECT_EQ(args.text(), "x");
  ASSERT_TRUE(args.next());
  EXPECT_EQ(args.flag(), "--count");
  EXPECT_EQ(args.integer(1), 3);
  ASSERT_TRUE(args.next());
  EXPECT_EQ(args.number(0.0, 1.0), 0.25);
  ASSERT_TRUE(args.next());
  EXPECT_TRUE(args.is("--quiet"));
  ASSERT_TRUE(args.next());
  EXPECT_EQ(args.integer64(0, UINT32_MAX), 4294967295LL);
  EXPECT_FALSE(args.next());
}

TEST(ArgReader, BadNumbersAreErrorsNamingTheFlagAndTheText) {
  auto integer = [](ArgReader& r) { r.integer(); };
  auto count = [](ArgReader& r) { r.integer(1); };
  auto threads = [](ArgReader& r) { r.integer(0); };
  auto number = [](ArgReader& r) { r.number(); };
  auto positive = [](ArgReader& r) { r.positive(); };
  EXPECT_EQ(errorOf("--threads", "abc", threads),
            "--threads: expected an integer >= 0, got 'abc'");
  EXPECT_EQ(errorOf("--count", "1x", count), "--count: expected an integer >= 1, got '1x'");
  EXPECT_EQ(errorOf("--count", "0", count), "--count: expected an integer >= 1, got '0'");
  EXPECT_EQ(errorOf("--max-disparity", "1e99", integer),
            "--max-disparity: expected an integer, got '1e99'");
  EXPECT_EQ(errorOf("--max-disparity", "", integer),
            "--max-disparity: expected an integer, got ''");
  EXPECT_EQ(errorOf("--noise", "1e999", number), "--noise: expected a number, got '1e999'");
  EXPECT_EQ(errorOf("--fps", "0", positive), "--fps: expected a number > 0, got '0'");
  EXPECT_EQ(errorOf("--fps", "-25", positive), "--fps: expected a number > 0, got '-25'");
  EXPECT_EQ(errorOf("--level", "11", [](ArgReader& r) { r.integer(0, 10); }),
            "--level: expected an integer from 0 to 10, got '11'");
  EXPECT_EQ(errorOf("--gain", "-1", [](ArgReader& r) { r.number(0.0); }),
            "--gain: expected a number >= 0, got '-1'");
  // Good values pass.
  EXPECT_EQ(errorOf("--threads", "0", threads), "");
  EXPECT_EQ(errorOf("--fps", "12.5", positive), "");
}

TEST(ArgReader, MissingValueAndUnknownFlag) {
  Argv a({"--left"});
  ArgReader args(a.argc(), a.argv());
  ASSERT_TRUE(args.next());
  try {
    args.text();
    ADD_FAILURE() << "no error for a missing value";
  } catch (const UsageError& e) {
    EXPECT_STREQ(e.what(), "--left needs a value");
  }
  try {
    args.unknown();
    ADD_FAILURE() << "no error for an unknown flag";
  } catch (const UsageError& e) {
    EXPECT_STREQ(e.what(), "unknown argument '--left' (see --help)");
  }
}

TEST(FramePatterns, OneIntegerConversionOnly) {
  using endo_stereo::tools::validPattern;
  EXPECT_TRUE(validPattern("left_%04d.png"));
  EXPECT_TRUE(validPattern("dir/%i.png"));
  EXPECT_TRUE(validPattern("100%%_%d.png"));
  EXPECT_FALSE(validPattern("left.png"));
  EXPECT_FALSE(validPattern("%d_%d.png"));
  EXPECT_FALSE(validPattern("%s.png"));
  EXPECT_FALSE(validPattern("%04"));
  EXPECT_EQ(endo_stereo::tools::formatPattern("l_%03d.png", 7), "l_007.png");
}

class FileSourceTest : public ::testing::Test {
 protected:
  void SetUp() override {
    char tmpl[] = "/tmp/es_tool_args_XXXXXX";
    ASSERT_NE(::mkdtemp(tmpl), nullptr);
    dir_ = tmpl;
  }
  void TearDown() override { std::system(("rm -rf '" + dir_ + "'").c_str()); }
  void write(const std::string& name, int cols, int rows) {
    ASSERT_TRUE(cv::imwrite(dir_ + "/" + name, cv::Mat(rows, cols, CV_8UC1, cv::Scalar(90))));
  }
  std::string dir_;
};

TEST_F(FileSourceTest, SequenceStartsAtOneWhenFrameZeroIsMissingAndStopsAtTheGap) {
  for (int i : {1, 2, 3, 5}) {
    write("l_" + std::to_string(i) + ".png", 32, 24);
    write("r_" + std::to_string(i) + ".png", 32, 24);
  }
  endo_stereo::tools::FrameSourceSettings s;
  s.left = dir_ + "/l_%d.png";
  s.right = dir_ + "/r_%d.png";
  s.fps = 10.0;
  auto source = endo_stereo::tools::makeFileFrameSource(s);
  ASSERT_EQ(source->size(), 3);
  EXPECT_EQ(source->emptyReason(), "");
  endo_stereo::tools::Frame f;
  std::string err;
  std::vector<int> indices;
  while (source->next(f, &err)) {
    indices.push_back(f.index);
    EXPECT_EQ(f.left_path, dir_ + "/l_" + std::to_string(f.index) + ".png");
    EXPECT_EQ(f.right_path, dir_ + "/r_" + std::to_string(f.index) + ".png");
    EXPECT_DOUBLE_EQ(f.input.stamp_s, f.index / 10.0);
    EXPECT_EQ(f.input.left_encoding, "mono8");
  }
  EXPECT_EQ(err, "");
  EXPECT_EQ(indices, (std::vector<int>{1, 2, 3}));
}

TEST_F(FileSourceTest, NoFrameSizeMismatchAndMissingFileAreNamed) {
  endo_stereo::tools::FrameSourceSettings s;
  s.left = dir_ + "/none_%03d.png";
  s.right = dir_ + "/none_r_%03d.png";
  auto empty = endo_stereo::tools::makeFileFrameSource(s);
  EXPECT_EQ(empty->size(), 0);
  EXPECT_EQ(empty->emptyReason(), "'" + dir_ + "/none_000.png' does not exist");

  write("a.png", 32, 24);
  write("b.png", 30, 24);
  endo_stereo::tools::FrameSourceSettings pair;
  pair.left = dir_ + "/a.png";
  pair.right = dir_ + "/b.png";
  auto mismatch = endo_stereo::tools::makeFileFrameSource(pair);
  ASSERT_EQ(mismatch->size(), 1);
  endo_stereo::tools::Frame f;
  std::string err;
  EXPECT_FALSE(mismatch->next(f, &err));
  EXPECT_NE(err.find("size mismatch"), std::string::npos) << err;
  EXPECT_NE(err.find("32x24"), std::string::npos) << err;

  endo_stereo::tools::FrameSourceSettings missing;
  missing.left = dir_ + "/a.png";
  missing.right = dir_ + "/missing.png";
  auto source = endo_stereo::tools::makeFileFrameSource(missing);
  err.clear();
  EXPECT_FALSE(source->next(f, &err));
  EXPECT_EQ(err, "cannot read image '" + dir_ + "/missing.png': no such file");
}

}  // namespace

int main(int argc, char** argv) {
  ::testing::InitGoogleTest(&argc, argv);
  return RUN_ALL_TESTS();
}
