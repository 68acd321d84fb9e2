// YAML presets, key=value overrides and the shared key list (params_io.hpp).
#include <gtest/gtest.h>
#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <regex>
#include <set>
#include <sstream>
#include <string>

#include "endo_stereo/core/params_io.hpp"

namespace {

using namespace endo_stereo;

std::string tempPath(const std::string& name) {
  return "/tmp/es_test_params_io_" + std::to_string(::getpid()) + "_" + name;
}

std::string writeFile(const std::string& name, const std::string& text) {
  const std::string path = tempPath(name);
  std::ofstream(path) << text;
  return path;
}

TEST(ParamsIo, ListsEveryKeyOnceUnderAKnownSection) {
  const PipelineParams p;
  const auto list = listPipelineParams(p);
  ASSERT_GT(list.size(), 20u);
  std::set<std::string> keys;
  const auto& sections = pipelineParamSections();
  for (const ParamInfo& info : list) {
    EXPECT_TRUE(keys.insert(info.key).second) << "duplicate key " << info.key;
    EXPECT_EQ(info.key, info.section + "." + info.field);
    EXPECT_NE(std::find(sections.begin(), sections.end(), info.section), sections.end())
        << info.key;
  }
  for (const char* k : {"matcher.delta_min", "matcher.window_min_px", "filter.outlier_min_share",
                        "output.point_cloud", "temporal.prior_radius_px"}) {
    EXPECT_EQ(keys.count(k), 1u) << k;
  }
}

TEST(ParamsIo, EveryKeyReadsBackTheTextItWasGiven) {
  PipelineParams p;
  for (const ParamInfo& info : listPipelineParams(PipelineParams())) {
    // A value different from the default, so a setter wired to the wrong field shows up.
    std::string text;
    switch (info.type) {
      case ParamType::kBool:
        text = info.value == "true" ? "false" : "true";
        break;
      case ParamType::kInt:
        text = std::to_string(std::stoi(info.value) + 3);
        break;
      case ParamType::kDouble:
        text = "0.375";
        break;
      case ParamType::kString:
        text = "some_text";
        for (const std::string& c : info.choices) {
          if (c != info.value) text = c;
        }
        break;
    }
    ASSERT_EQ(setPipelineParam(p, info.key, text), "") << info.key;
    std::string back;
    ASSERT_TRUE(getPipelineParam(p, info.key, &back));
    EXPECT_EQ(back, text) << info.key;
  }
  // Each key owns a distinct field: every one of them now differs from the defaults.
  const auto defaults = listPipelineParams(PipelineParams());
  const auto changed = listPipelineParams(p);
  ASSERT_EQ(defaults.size(), changed.size());
  for (size_t i = 0; i < defaults.size(); ++i) {
    if (defaults[i].type == ParamType::kString && defaults[i].choices.size() == 1) continue;
    EXPECT_NE(defaults[i].value, changed[i].value) << defaults[i].key;
  }
}

TEST(ParamsIo, YamlWrittenLoadsBackToTheSameParams) {
  PipelineParams p;
  p.matcher.delta_min = 0.1234567890123;
  p.matcher.window_max_px = 23;
  p.filter.fill_holes = false;
  p.temporal.max_gap_s = 1.5;
  p.output.point_cloud = false;
  const std::string yaml = pipelineParamsToYaml(p);
  PipelineParams q;
  ASSERT_EQ(loadPipelineParamsFromString(yaml, q), "");
  EXPECT_EQ(pipelineParamsToYaml(q), yaml);
  EXPECT_EQ(q.matcher.delta_min, 0.1234567890123);  // shortest round-trip text: exact
  EXPECT_EQ(q.matcher.window_max_px, 23);
  EXPECT_FALSE(q.filter.fill_holes);
}

TEST(ParamsIo, FileLayersOnTopAndKeepsAbsentKeys) {
  PipelineParams p;
  p.matcher.window_min_px = 9;  // set before loading; the file does not mention it
  const std::string path = writeFile("layer.yaml",
                                     "matcher:\n  delta_min: 0.25\n  subpixel: off\n"
                                     "filter:\n  outlier_window_px: 7\n"
                                     "ros:\n  queue_size: 5\n");
  ASSERT_EQ(loadPipelineParams(path, p), "");
  EXPECT_DOUBLE_EQ(p.matcher.delta_min, 0.25);
  EXPECT_FALSE(p.matcher.subpixel);
  EXPECT_EQ(p.filter.outlier_window_px, 7);
  EXPECT_EQ(p.matcher.window_min_px, 9);
  std::remove(path.c_str());
}

TEST(ParamsIo, UnknownKeyInFileIsAnErrorNamingItAndChangesNothing) {
  PipelineParams p;
  const std::string before = pipelineParamsToYaml(p);
  const std::string path =
      writeFile("unknown.yaml", "matcher:\n  delta_min: 0.3\n  delta_minn: 0.2\n");
  const std::string err = loadPipelineParams(path, p);
  EXPECT_NE(err.find("matcher.delta_minn"), std::string::npos) << err;
  EXPECT_NE(err.find(path), std::string::npos) << err;
  EXPECT_EQ(pipelineParamsToYaml(p), before);  // all or nothing: delta_min was not applied
  std::remove(path.c_str());
}

TEST(ParamsIo, UnknownSectionAndNonScalarValuesAreErrors) {
  PipelineParams p;
  std::string err = loadPipelineParamsFromString("matchr:\n  delta_min: 0.3\n", p);
  EXPECT_NE(err.find("matchr"), std::string::npos) << err;
  err = loadPipelineParamsFromString("matcher:\n  delta_min: [0.1, 0.2]\n", p);
  EXPECT_NE(err.find("matcher.delta_min"), std::string::npos) << err;
  err = loadPipelineParamsFromString("matcher: 3\n", p);
  EXPECT_NE(err.find("matcher"), std::string::npos) << err;
  err = loadPipelineParamsFromString("- a\n- b\n", p);
  EXPECT_FALSE(err.empty());
  err = loadPipelineParamsFromString("matcher: {delta_min: 0.3\n", p);
  EXPECT_NE(err.find("YAML"), std::string::npos) << err;
}

TEST(ParamsIo, BadValuesAreErrorsNamingTheKey) {
  PipelineParams p;
  const std::string before = pipelineParamsToYaml(p);
  struct Case {
    const char* key;
    const char* value;
    const char* expect;
  };
  for (const Case& c :
       {Case{"matcher.window_min_px", "7.5", "integer"},
        Case{"matcher.window_min_px", "", "integer"}, Case{"matcher.delta_min", "abc", "number"},
        Case{"matcher.delta_min", "nan", "number"}, Case{"matcher.delta_min", "0.2x", "number"},
        Case{"matcher.subpixel", "maybe", "boolean"},
        Case{"matcher.max_disparity", "99999999999", "integer"}}) {
    const std::string err = setPipelineParam(p, c.key, c.value);
    EXPECT_NE(err.find(c.key), std::string::npos) << c.key << "=" << c.value << ": " << err;
    EXPECT_NE(err.find(c.expect), std::string::npos) << err;
  }
  EXPECT_EQ(pipelineParamsToYaml(p), before);
  const std::string err =
      loadPipelineParamsFromString("filter:\n  outlier_window_px: five\n", p, "preset.yaml");
  EXPECT_NE(err.find("preset.yaml"), std::string::npos) << err;
  EXPECT_NE(err.find("filter.outlier_window_px"), std::string::npos) << err;
}

TEST(ParamsIo, OverridesParseKeyEqualsValue) {
  PipelineParams p;
  EXPECT_EQ(applyParamOverride(p, "matcher.delta_min=0.2"), "");
  EXPECT_DOUBLE_EQ(p.matcher.delta_min, 0.2);
  EXPECT_EQ(applyParamOverride(p, "matcher.max_disparity=+40"), "");
  EXPECT_EQ(p.matcher.max_disparity, 40);
  EXPECT_EQ(applyParamOverride(p, "matcher.min_disparity=-8"), "");
  EXPECT_EQ(p.matcher.min_disparity, -8);
  EXPECT_NE(applyParamOverride(p, "matcher.delta_min").find("malformed"), std::string::npos);
  EXPECT_NE(applyParamOverride(p, "=3").find("malformed"), std::string::npos);
  const std::string err = applyParamOverride(p, "matcher.nope=1");
  EXPECT_NE(err.find("matcher.nope"), std::string::npos) << err;
  EXPECT_NE(err.find("delta_min"), std::string::npos) << "lists the known keys: " << err;
}

TEST(ParamsIo, MissingFileIsAnError) {
  PipelineParams p;
  const std::string err = loadPipelineParams("/nonexistent/preset.yaml", p);
  EXPECT_NE(err.find("/nonexistent/preset.yaml"), std::string::npos) << err;
}

// The shipped presets load with this loader and pass validation; the paper preset holds the
// paper's values (docs/method.md, "Parameters").
TEST(ParamsIo, ShippedPresetsLoadAndPaperPresetHoldsThePapersValues) {
  const std::string dir = std::string(ES_SOURCE_DIR) + "/config/";
  for (const char* name : {"default.yaml", "paper.yaml"}) {
    ASSERT_TRUE(std::ifstream(dir + name).good()) << "config/" << name << " is missing";
    PipelineParams p;
    EXPECT_EQ(loadPipelineParams(dir + name, p), "") << name;
    EXPECT_EQ(p.validate(), "") << name;
  }
  PipelineParams paper;
  ASSERT_EQ(loadPipelineParams(dir + "paper.yaml", paper), "");
  EXPECT_DOUBLE_EQ(paper.matcher.gamma_min, 0.5);
  EXPECT_DOUBLE_EQ(paper.matcher.delta_min, 0.1);
  EXPECT_DOUBLE_EQ(paper.matcher.epsilon_px, 5.0);
  EXPECT_EQ(paper.matcher.window_min_px, 7);
  EXPECT_EQ(paper.matcher.window_step_px, 4);
  EXPECT_EQ(paper.matcher.window_max_px, 30);
  EXPECT_EQ(paper.filter.outlier_window_px, 5);
  EXPECT_DOUBLE_EQ(paper.filter.outlier_disparity_tol_px, 4.0);
  EXPECT_DOUBLE_EQ(paper.filter.outlier_min_share, 0.4);
}

// The struct defaults are documented as the shipped default preset (matcher.hpp, temporal.hpp):
// config/default.yaml must not say otherwise.
TEST(ParamsIo, DefaultPresetFileEqualsTheStructDefaults) {
  PipelineParams from_file;
  ASSERT_EQ(loadPipelineParams(std::string(ES_SOURCE_DIR) + "/config/default.yaml", from_file), "");
  const auto a = listPipelineParams(PipelineParams());
  const auto b = listPipelineParams(from_file);
  ASSERT_EQ(a.size(), b.size());
  for (size_t i = 0; i < a.size(); ++i) EXPECT_EQ(a[i].value, b[i].value) << a[i].key;
}

// Every field of every params struct has a key: the headers are read and each field declared
// with a default (`type name = value;`) inside the struct body must be listed. Guards against a
// field added to a struct but not to the table in params_io.cpp.
TEST(ParamsIo, EveryParamsStructFieldHasAKey) {
  struct Source {
    const char* header;
    const char* strukt;
    const char* section;
  };
  const Source sources[] = {{"matcher.hpp", "MatcherParams", "matcher"},
                            {"post_filter.hpp", "PostFilterParams", "filter"},
                            {"preprocess.hpp", "PreprocessParams", "preprocess"},
                            {"rectification.hpp", "RectifyParams", "rectify"},
                            {"temporal.hpp", "TemporalParams", "temporal"},
                            {"pipeline.hpp", "OutputParams", "output"}};
  std::set<std::string> keys;
  for (const ParamInfo& info : listPipelineParams(PipelineParams())) keys.insert(info.key);
  for (const Source& src : sources) {
    std::ifstream in(std::string(ES_SOURCE_DIR) + "/include/endo_stereo/core/" + src.header);
    ASSERT_TRUE(in.good()) << src.header;
    std::stringstream text;
    text << in.rdbuf();
    const std::string all = text.str();
    const size_t begin = all.find(std::string("struct ") + src.strukt + " {");
    ASSERT_NE(begin, std::string::npos) << src.strukt;
    const size_t end = all.find("\n};", begin);
    const std::string body = all.substr(begin, end - begin);
    const std::regex field_re(R"(\n\s+[A-Za-z_:<>]+ ([a-z_0-9]+) = [^;]*;)");
    int found = 0;
    for (auto it = std::sregex_iterator(body.begin(), body.end(), field_re);
         it != std::sregex_iterator(); ++it) {
      const std::string key = std::string(src.section) + "." + (*it)[1].str();
      EXPECT_EQ(keys.count(key), 1u)
          << key << " (" << src.strukt << ") has no entry in src/core/pipeline/param_table.cpp";
      ++found;
    }
    EXPECT_GT(found, 0) << src.strukt;
  }
}


// --- the parameter table: ranges, meanings, presets and the README agree with it ----------------

// validate()'s verdict on the defaults with one key set to @p value: "" = accepted, else the
// message. A message about another key (a cross-field rule) is not this key's verdict.
std::string verdict(const ParamInfo& info, double value) {
  PipelineParams p;
  char text[64];
  std::snprintf(text, sizeof(text), "%.17g", value);
  EXPECT_EQ(setPipelineParam(p, info.key, text), "") << info.key << " = " << text;
  return p.validate();
}

bool names(const std::string& message, const ParamInfo& info) {
  return message.find(info.field) != std::string::npos;
}

// The table's range of each number is what validate() enforces: values just outside a bound are
// refused with a message naming the key, values at a closed bound (or next to an open one) are
// accepted. Where the range is not a plain interval (odd widths, a bound set by another field),
// only the outer limits are checked, as refusals.
TEST(ParamTable, RangesAreWhatValidateEnforces) {
  int checked = 0;
  for (const ParamInfo& info : listPipelineParams(PipelineParams())) {
    if (info.type != ParamType::kInt && info.type != ParamType::kDouble) continue;
    const ParamBounds& b = info.bounds;
    const bool is_int = info.type == ParamType::kInt;
    // Just outside: the next integer, or the next representable double (exact for these bounds).
    auto below = [&](double v) { return is_int ? v - 1.0 : std::nextafter(v, -HUGE_VAL); };
    auto beyond = [&](double v) { return is_int ? v + 1.0 : std::nextafter(v, HUGE_VAL); };
    if (std::isfinite(b.lo)) {
      const double out = b.lo_open ? b.lo : below(b.lo);
      const std::string m = verdict(info, out);
      EXPECT_TRUE(names(m, info)) << info.key << " = " << out << " accepted: '" << m << "'";
      ++checked;
      if (b.exact) {
        const double at = b.lo_open ? beyond(b.lo) : b.lo;
        EXPECT_EQ(verdict(info, at), "") << info.key << " = " << at;
      }
    }
    if (std::isfinite(b.hi)) {
      const double out = b.hi_open ? b.hi : beyond(b.hi);
      const std::string m = verdict(info, out);
      EXPECT_TRUE(names(m, info)) << info.key << " = " << out << " accepted: '" << m << "'";
      ++checked;
      if (b.exact) {
        const double at = b.hi_open ? below(b.hi) : b.hi;
        EXPECT_EQ(verdict(info, at), "") << info.key << " = " << at;
      }
    }
  }
  EXPECT_GT(checked, 60);  // about 75 bounds in the table today
}

TEST(ParamTable, EveryKeyHasAMeaningAnOriginAndARangeUnlessBoolean) {
  int paper = 0, ours = 0;
  for (const ParamInfo& info : listPipelineParams(PipelineParams())) {
    EXPECT_FALSE(info.meaning.empty()) << info.key;
    EXPECT_EQ(info.range.empty(), info.type == ParamType::kBool) << info.key;
    EXPECT_EQ(info.default_value, info.value) << info.key;  // listed from the defaults
    paper += info.origin == ParamOrigin::kPaper;
    ours += info.origin == ParamOrigin::kOurs;
  }
  EXPECT_GE(paper, 10);  // docs/method.md's table of the paper's parameters
  EXPECT_GE(ours, 10);
}

// Both presets hold only keys of the table, and every number in them lies within its bounds.
TEST(ParamTable, PresetValuesLieWithinTheTablesRanges) {
  for (const char* name : {"default.yaml", "paper.yaml"}) {
    PipelineParams p;
    ASSERT_EQ(loadPipelineParams(std::string(ES_SOURCE_DIR) + "/config/" + name, p), "") << name;
    for (const ParamInfo& info : listPipelineParams(p)) {
      if (info.type != ParamType::kInt && info.type != ParamType::kDouble) continue;
      const double v = std::stod(info.value);
      const ParamBounds& b = info.bounds;
      EXPECT_TRUE(b.lo_open ? v > b.lo : v >= b.lo) << name << ": " << info.key << " = " << v;
      EXPECT_TRUE(b.hi_open ? v < b.hi : v <= b.hi) << name << ": " << info.key << " = " << v;
    }
  }
}

// README.md shows the table between its markers as paramTableMarkdown() writes it; regenerate
// with `make params-table` after changing src/core/pipeline/param_table.cpp.
TEST(ParamTable, TheReadmeShowsTheGeneratedTable) {
  std::ifstream in(std::string(ES_SOURCE_DIR) + "/README.md");
  ASSERT_TRUE(in.good());
  std::stringstream text;
  text << in.rdbuf();
  const std::string readme = text.str();
  const std::string begin = "<!-- params-table:begin -->\n", end = "<!-- params-table:end -->";
  const size_t a = readme.find(begin), b = readme.find(end);
  ASSERT_NE(a, std::string::npos) << "README.md has no " << begin;
  ASSERT_NE(b, std::string::npos) << "README.md has no " << end;
  EXPECT_EQ(readme.substr(a + begin.size(), b - a - begin.size()), paramTableMarkdown())
      << "README.md's parameter table is stale: run `make params-table`";
}

}  // namespace

int main(int argc, char** argv) {
  ::testing::InitGoogleTest(&argc, argv);
  return RUN_ALL_TESTS();
}
