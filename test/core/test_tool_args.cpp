// The tools' shared pieces: argument reading (a bad number is an error naming the flag and the
// text; the flags several tools share, each tool's groups and ranges; a tool's run and its exit
// statuses) and the image-file frame source (patterns, first index, counts, errors).
#include <gtest/gtest.h>
#include <unistd.h>

#include <climits>
#include <cstdlib>
#include <functional>
#include <opencv2/imgcodecs.hpp>
#include <stdexcept>
#include <string>
#include <vector>

#include "frame_sources.hpp"
#include "tool_args.hpp"

namespace {

using endo_stereo::tools::ArgReader;
using endo_stereo::tools::SharedOptions;
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

// The groups of the shared flags that endo_stereo_cli takes.
constexpr unsigned kCliFlags = endo_stereo::tools::kFlagLeftRight | endo_stereo::tools::kFlagFirst |
                               endo_stereo::tools::kFlagCount | endo_stereo::tools::kFlagFps |
                               endo_stereo::tools::kFlagParams |
                               endo_stereo::tools::kFlagDisparityRange |
                               endo_stereo::tools::kFlagThreads | endo_stereo::tools::kFlagQuiet;

// Reads every word of @p words with readArguments into @p o (no flag of the tool's own); the
// message of the UsageError thrown, "" when none is.
std::string readAll(const std::vector<std::string>& words, SharedOptions& o) {
  Argv a(words);
  try {
    endo_stereo::tools::readArguments(a.argc(), a.argv(), "usage\n", o,
                                      [](ArgReader&) { return false; });
  } catch (const UsageError& e) {
    return e.what();
  }
  return "";
}

TEST(SharedOptions, ReadsTheFlagsOfTheGroupsATakes) {
  SharedOptions o(kCliFlags);
  const std::vector<std::string> words = endo_stereo::tools::splitList(
      "--left l_%d.png --right r_%d.png --first 3 --count 5 --fps 12.5 --params p.yaml "
      "--set a.b=1 --set c.d=2 --calib c.yaml --min-disparity -4 --max-disparity 60 --threads 2 "
      "--quiet",
      ' ');
  EXPECT_EQ(readAll(words, o), "");
  EXPECT_EQ(o.left, "l_%d.png");
  EXPECT_EQ(o.right, "r_%d.png");
  EXPECT_TRUE(o.has_first);
  EXPECT_EQ(o.first, 3);
  EXPECT_EQ(o.count, 5);
  EXPECT_EQ(o.fps, 12.5);
  EXPECT_EQ(o.params_file, "p.yaml");
  EXPECT_EQ(o.overrides, (std::vector<std::string>{"a.b=1", "c.d=2"}));
  EXPECT_EQ(o.calib, "c.yaml");
  EXPECT_TRUE(o.has_min && o.has_max);
  EXPECT_EQ(o.min_disparity, -4);
  EXPECT_EQ(o.max_disparity, 60);
  EXPECT_TRUE(o.has_threads);
  EXPECT_EQ(o.threads, 2);
  EXPECT_TRUE(o.quiet);

  // Defaults when not given.
  SharedOptions d(kCliFlags);
  EXPECT_EQ(readAll({}, d), "");
  EXPECT_FALSE(d.has_first || d.has_min || d.has_max || d.has_threads || d.quiet);
  EXPECT_EQ(d.count, -1);
  EXPECT_EQ(d.fps, 25.0);
  EXPECT_EQ(d.ns, "/endoscope");

  // Flags of groups the tool does not take are unknown to it.
  for (const char* other : {"--bag", "--namespace", "--out"}) {
    SharedOptions c(kCliFlags);
    EXPECT_EQ(readAll({other, "x"}, c),
              std::string("unknown argument '") + other + "' (see --help)");
  }
  SharedOptions bag(endo_stereo::tools::kFlagBag | endo_stereo::tools::kFlagOutDir);
  EXPECT_EQ(readAll({"--bag", "b.bag", "--namespace", "/ns/", "--out", "dir"}, bag), "");
  EXPECT_EQ(bag.bag, "b.bag");
  EXPECT_EQ(bag.ns, "/ns/");  // as given
  EXPECT_EQ(bag.out_dir, "dir");
  EXPECT_EQ(readAll({"--left", "x"}, bag), "unknown argument '--left' (see --help)");
}

TEST(SharedOptions, ValuesKeepTheToolsRanges) {
  SharedOptions o(kCliFlags);
  EXPECT_EQ(readAll({"--first", "-1"}, o), "--first: expected an integer >= 0, got '-1'");
  EXPECT_EQ(readAll({"--count", "x"}, o), "--count: expected an integer >= 1, got 'x'");
  EXPECT_EQ(readAll({"--fps", "0"}, o), "--fps: expected a number > 0, got '0'");
  EXPECT_EQ(readAll({"--threads", "-1"}, o), "--threads: expected an integer >= 0, got '-1'");
  EXPECT_EQ(readAll({"--min-disparity", "x"}, o), "--min-disparity: expected an integer, got 'x'");
  EXPECT_EQ(readAll({"--set"}, o), "--set needs a value");

  endo_stereo::tools::SharedRanges floor;
  floor.disparity_min = -100000;
  SharedOptions f(kCliFlags, floor);
  EXPECT_EQ(readAll({"--max-disparity", "-200000"}, f),
            "--max-disparity: expected an integer >= -100000, got '-200000'");

  endo_stereo::tools::SharedRanges any;
  any.first_min = INT_MIN;
  any.threads_min = INT_MIN;
  any.fps_positive = false;
  SharedOptions a(kCliFlags, any);
  EXPECT_EQ(readAll({"--first", "-1", "--threads", "-1", "--fps", "-3"}, a), "");
  EXPECT_EQ(a.first, -1);
  EXPECT_EQ(a.threads, -1);
  EXPECT_EQ(a.fps, -3.0);
  EXPECT_EQ(readAll({"--fps", "x"}, a), "--fps: expected a number, got 'x'");
}

TEST(SharedOptions, OwnFlagsGoToTheToolsReaderAndHelpExits) {
  SharedOptions o(kCliFlags);
  Argv a({"--count", "2", "--mine", "7", "--quiet"});
  int mine = 0;
  endo_stereo::tools::readArguments(a.argc(), a.argv(), "usage\n", o, [&mine](ArgReader& args) {
    if (!args.is("--mine")) return false;
    mine = args.integer();
    return true;
  });
  EXPECT_EQ(mine, 7);
  EXPECT_EQ(o.count, 2);
  EXPECT_TRUE(o.quiet);

  Argv h({"--count", "2", "--help", "--bogus"});
  EXPECT_EXIT(endo_stereo::tools::readArguments(h.argc(), h.argv(), "the usage\n", o,
                                                [](ArgReader&) { return false; }),
              ::testing::ExitedWithCode(0), "");
}

TEST(SharedOptions, FrameSourceSettingsTakeTheInputFlags) {
  SharedOptions o(kCliFlags | endo_stereo::tools::kFlagBag);
  ASSERT_EQ(readAll({"--left", "l", "--right", "r", "--first", "2", "--count", "4", "--fps", "10",
                     "--bag", "b.bag", "--namespace", "/x"},
                    o),
            "");
  const endo_stereo::tools::FrameSourceSettings s = endo_stereo::tools::frameSourceSettings(o);
  EXPECT_EQ(s.left, "l");
  EXPECT_EQ(s.right, "r");
  EXPECT_TRUE(s.has_first);
  EXPECT_EQ(s.first, 2);
  EXPECT_EQ(s.count, 4);
  EXPECT_EQ(s.fps, 10.0);
  EXPECT_EQ(s.bag_path, "b.bag");
  EXPECT_EQ(s.ns, "/x");
  EXPECT_EQ(s.repeat, 0);
  EXPECT_EQ(s.crop.area(), 0);
}

TEST(RunTool, ErrorsAreSaidAfterTheToolsNameWithTheirExitStatus) {
  auto run = [](const std::function<int()>& body, std::string* said) {
    ::testing::internal::CaptureStderr();
    const int status = endo_stereo::tools::runTool("tool", body);
    *said = ::testing::internal::GetCapturedStderr();
    return status;
  };
  std::string said;
  EXPECT_EQ(run([] { return 0; }, &said), 0);
  EXPECT_EQ(said, "");
  EXPECT_EQ(run([]() -> int { throw UsageError("bad flag"); }, &said),
            endo_stereo::tools::kExitUsage);
  EXPECT_EQ(said, "tool: bad flag\n");
  EXPECT_EQ(run([]() -> int { throw endo_stereo::tools::InputError{"no file"}; }, &said),
            endo_stereo::tools::kExitInput);
  EXPECT_EQ(said, "tool: no file\n");
  EXPECT_EQ(run([]() -> int { throw std::runtime_error("boom"); }, &said),
            endo_stereo::tools::kExitInput);
  EXPECT_EQ(said, "tool: unexpected error: boom\n");
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
