#include "endo_stereo/core/calibration_io.hpp"

#include <yaml-cpp/yaml.h>

#include <cmath>
#include <cstdint>
#include <fstream>
#include <iomanip>
#include <opencv2/core/persistence.hpp>
#include <sstream>
#include <string>
#include <vector>

namespace endo_stereo {

namespace {

bool fail(std::string* error, const std::string& msg) {
  if (error) *error = msg;
  return false;
}

bool readFile(const std::string& path, std::string* text) {
  std::ifstream is(path, std::ios::binary);
  if (!is) return false;
  std::ostringstream ss;
  ss << is.rdbuf();
  *text = ss.str();
  return true;
}

/// A camera_info matrix block {rows, cols, data}; checks the declared and the expected size.
bool readYamlMatrix(const YAML::Node& root, const std::string& key, int rows, int cols,
                    bool required, std::vector<double>* values, std::string* error) {
  const YAML::Node node = root[key];
  if (!node) {
    if (required) return fail(error, key + ": missing");
    values->clear();
    return true;
  }
  try {
    const YAML::Node data = node["data"] ? node["data"] : node;
    if (!data.IsSequence()) return fail(error, key + ".data: not a sequence");
    values->clear();
    for (const auto& v : data) values->push_back(v.as<double>());
    if (node["rows"] && node["cols"]) {
      const int r = node["rows"].as<int>(), c = node["cols"].as<int>();
      if (size_t(r) * size_t(c) != values->size()) {
        return fail(error, key + ": rows x cols = " + std::to_string(r) + "x" + std::to_string(c) +
                               " but data has " + std::to_string(values->size()) + " values");
      }
      if (rows > 0 && (r != rows || c != cols)) {
        return fail(error, key + ": must be " + std::to_string(rows) + "x" + std::to_string(cols) +
                               ", got " + std::to_string(r) + "x" + std::to_string(c));
      }
    } else if (rows > 0 && int(values->size()) != rows * cols) {
      return fail(error, key + ": must have " + std::to_string(rows * cols) + " values, got " +
                             std::to_string(values->size()));
    }
  } catch (const std::exception& ex) {
    return fail(error, key + ": " + ex.what());
  }
  return true;
}

template <int R, int C>
cv::Matx<double, R, C> toMatx(const std::vector<double>& v) {
  cv::Matx<double, R, C> m;
  for (int i = 0; i < R * C; ++i) m.val[i] = v[i];
  return m;
}

std::string modelForCount(size_t n) {
  if (n == 0) return "";
  return n == 8 ? "rational_polynomial" : "plumb_bob";
}

/// Fill the right camera's extrinsics-free baseline check and validate.
bool finish(StereoCalibration& out, const std::string& where, std::string* error) {
  const std::string e = out.validate();
  if (!e.empty()) return fail(error, where + ": " + e);
  return true;
}

/// Largest row or column count a matrix of a calibration file may declare (the largest one read
/// here is 3x4; distortion vectors have at most 14 coefficients).
constexpr int kMaxCalibMatrixSide = 64;

/// Checks the shape a FileStorage matrix node declares against the values it holds, before
/// cv::read() allocates it: OpenCV allocates rows x cols x channels from the header first and
/// compares with the data only afterwards, so a corrupted header ("rows: 2147483647") made the
/// loader ask for 16 GB (found by fuzz_opencv_stereo). @return "" or what is wrong.
std::string checkMatrixNode(const cv::FileNode& n) {
  if (!n.isMap()) return "";  // a plain sequence or scalar: cv::read() makes an empty matrix
  const cv::FileNode data = n["data"];
  const int64_t values = data.empty() ? 0 : static_cast<int64_t>(data.size());
  int64_t declared = 1;
  auto side = [&](const cv::FileNode& v, const char* what) -> std::string {
    if (!v.isInt() && !v.isReal()) return std::string(what) + ": not a number";
    const double x = static_cast<double>(v);
    if (!(x >= 0 && x <= kMaxCalibMatrixSide) || x != std::floor(x)) {
      std::ostringstream os;
      os.precision(17);
      os << what << " = " << x << " is not an integer in 0.." << kMaxCalibMatrixSide;
      return os.str();
    }
    declared *= static_cast<int64_t>(x);
    return "";
  };
  const cv::FileNode sizes = n["sizes"];
  std::string why;
  if (!sizes.empty()) {
    if (!sizes.isSeq() || sizes.size() > 4) return "sizes: not a list of at most 4 integers";
    for (int i = 0; i < static_cast<int>(sizes.size()) && why.empty(); ++i) {
      why = side(sizes[i], "sizes");
    }
  } else {
    why = side(n["rows"], "rows");
    if (why.empty()) why = side(n["cols"], "cols");
  }
  if (!why.empty()) return why;
  if (declared > values) {
    return "declares " + std::to_string(declared) + " elements but holds " +
           std::to_string(values) + " values";
  }
  return "";
}

/// Reads matrix @p key as CV_64F. @return false when it is missing or empty, or (with @p why set)
/// when its declared shape is impossible.
bool readCvMat(const cv::FileStorage& fs, const char* key, cv::Mat* m, std::string* why) {
  why->clear();
  cv::FileNode n = fs[key];
  if (n.empty()) return false;
  *why = checkMatrixNode(n);
  if (!why->empty()) return false;
  n >> *m;
  if (m->empty()) return false;
  m->convertTo(*m, CV_64F);
  return true;
}

bool matToMatx33(const cv::Mat& m, cv::Matx33d* out) {
  if (m.rows != 3 || m.cols != 3) return false;
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 3; ++c) (*out)(r, c) = m.at<double>(r, c);
  return true;
}

bool matToMatx34(const cv::Mat& m, cv::Matx34d* out) {
  if (m.rows != 3 || m.cols != 4) return false;
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 4; ++c) (*out)(r, c) = m.at<double>(r, c);
  return true;
}

std::string sizeString(const cv::Mat& m) {
  return std::to_string(m.rows) + "x" + std::to_string(m.cols);
}

/// Whitespace-separated numbers of a text file.
bool readNumbers(const std::string& path, std::vector<double>* values, std::string* error) {
  std::string text;
  if (!readFile(path, &text)) return fail(error, path + ": cannot read");
  std::istringstream is(text);
  values->clear();
  std::string tok;
  while (is >> tok) {
    try {
      size_t used = 0;
      values->push_back(std::stod(tok, &used));
      if (used != tok.size()) return fail(error, path + ": not a number: '" + tok + "'");
    } catch (const std::exception&) {
      return fail(error, path + ": not a number: '" + tok + "'");
    }
  }
  return true;
}

std::string joinPath(const std::string& dir, const std::string& name) {
  if (dir.empty() || dir.back() == '/') return dir + name;
  return dir + "/" + name;
}

}  // namespace

bool parseCameraInfoYaml(const std::string& text, CameraCalibration& out, std::string* error) {
  YAML::Node root;
  try {
    root = YAML::Load(text);
  } catch (const std::exception& ex) {
    return fail(error, std::string("not valid YAML: ") + ex.what());
  }
  if (!root.IsMap()) return fail(error, "not a camera_info YAML map");
  CameraCalibration c;
  try {
    if (!root["image_width"]) return fail(error, "image_width: missing");
    if (!root["image_height"]) return fail(error, "image_height: missing");
    c.width = root["image_width"].as<int>();
    c.height = root["image_height"].as<int>();
    if (root["camera_name"]) c.frame_id = root["camera_name"].as<std::string>();
    if (root["distortion_model"]) c.distortion_model = root["distortion_model"].as<std::string>();
    if (root["binning_x"]) c.binning_x = root["binning_x"].as<int>();
    if (root["binning_y"]) c.binning_y = root["binning_y"].as<int>();
    if (root["roi"]) {
      const YAML::Node r = root["roi"];
      c.roi = cv::Rect(
          r["x_offset"] ? r["x_offset"].as<int>() : 0, r["y_offset"] ? r["y_offset"].as<int>() : 0,
          r["width"] ? r["width"].as<int>() : 0, r["height"] ? r["height"].as<int>() : 0);
    }
  } catch (const std::exception& ex) {
    return fail(error, std::string("bad scalar field: ") + ex.what());
  }
  std::vector<double> v;
  if (!readYamlMatrix(root, "camera_matrix", 3, 3, true, &v, error)) return false;
  c.K = toMatx<3, 3>(v);
  if (!readYamlMatrix(root, "distortion_coefficients", 0, 0, false, &v, error)) return false;
  c.D = v;
  if (c.distortion_model.empty()) c.distortion_model = modelForCount(c.D.size());
  if (!readYamlMatrix(root, "rectification_matrix", 3, 3, false, &v, error)) return false;
  if (!v.empty()) c.R = toMatx<3, 3>(v);
  if (!readYamlMatrix(root, "projection_matrix", 3, 4, false, &v, error)) return false;
  if (!v.empty()) c.P = toMatx<3, 4>(v);
  const std::string e = c.validate("camera");
  if (!e.empty()) return fail(error, e);
  out = c;
  return true;
}

bool loadCameraInfoYaml(const std::string& path, CameraCalibration& out, std::string* error) {
  std::string text;
  if (!readFile(path, &text)) return fail(error, path + ": cannot read");
  std::string e;
  if (!parseCameraInfoYaml(text, out, &e)) return fail(error, path + ": " + e);
  return true;
}

std::string cameraInfoYamlString(const CameraCalibration& c, const std::string& camera_name) {
  std::ostringstream os;
  os << std::setprecision(17);
  auto matrix = [&](const char* key, int rows, int cols, const double* data, size_t n) {
    os << key << ":\n  rows: " << rows << "\n  cols: " << cols << "\n  data: [";
    for (size_t i = 0; i < n; ++i) os << (i ? ", " : "") << data[i];
    os << "]\n";
  };
  std::vector<double> d = c.D;
  std::string model = c.distortion_model.empty() ? "plumb_bob" : c.distortion_model;
  if (model == "plumb_bob" && d.size() < 5) d.resize(5, 0.0);
  os << "image_width: " << c.width << "\nimage_height: " << c.height
     << "\ncamera_name: " << (camera_name.empty() ? "camera" : camera_name) << "\n";
  matrix("camera_matrix", 3, 3, c.K.val, 9);
  os << "distortion_model: " << model << "\n";
  matrix("distortion_coefficients", 1, int(d.size()), d.data(), d.size());
  matrix("rectification_matrix", 3, 3, c.R.val, 9);
  matrix("projection_matrix", 3, 4, c.P.val, 12);
  if ((c.binning_x > 1) || (c.binning_y > 1)) {
    os << "binning_x: " << c.binning_x << "\nbinning_y: " << c.binning_y << "\n";
  }
  if (c.roi.area() > 0) {
    os << "roi:\n  x_offset: " << c.roi.x << "\n  y_offset: " << c.roi.y
       << "\n  width: " << c.roi.width << "\n  height: " << c.roi.height << "\n";
  }
  return os.str();
}

bool saveCameraInfoYaml(const std::string& path, const CameraCalibration& c,
                        const std::string& camera_name, std::string* error) {
  std::ofstream os(path);
  if (!os) return fail(error, path + ": cannot open for writing");
  os << cameraInfoYamlString(c, camera_name);
  if (!os) return fail(error, path + ": write failed");
  return true;
}

bool loadStereoCameraInfoYaml(const std::string& left_path, const std::string& right_path,
                              StereoCalibration& out, std::string* error) {
  StereoCalibration s;
  if (!loadCameraInfoYaml(left_path, s.left, error)) return false;
  if (!loadCameraInfoYaml(right_path, s.right, error)) return false;
  s.has_extrinsics = false;
  if (!finish(s, left_path + " + " + right_path, error)) return false;
  out = s;
  return true;
}

bool loadOpenCvStereoYaml(const std::string& path, StereoCalibration& out, std::string* error,
                          double translation_scale) {
  // OpenCV 4.6's XML parser dereferences a null pointer on a NUL byte inside the text (found by
  // fuzz_opencv_stereo: a SIGSEGV no try/catch can turn into an error). A YAML, XML or JSON file
  // has no NUL byte, so such a file is refused before the parser sees it (gzip files excepted).
  const bool gzip = path.size() > 3 && path.compare(path.size() - 3, 3, ".gz") == 0;
  if (!gzip) {
    std::string text;
    if (!readFile(path, &text)) return fail(error, path + ": cannot open");
    const size_t nul = text.find('\0');
    if (nul != std::string::npos) {
      return fail(error, path + ": NUL byte at offset " + std::to_string(nul) +
                             ": not a text (YAML, XML or JSON) file");
    }
  }
  cv::FileStorage fs;
  try {
    if (!fs.open(path, cv::FileStorage::READ)) return fail(error, path + ": cannot open");
  } catch (const std::exception& ex) {
    // cv::Exception, but FileStorage also lets std::length_error and the like escape.
    return fail(error, path + ": not an OpenCV FileStorage file: " + ex.what());
  }
  StereoCalibration s;
  cv::Mat m1, d1, m2, d2, r, t, r1, r2, p1, p2;
  try {
    std::string why;
    // A matrix with an impossible shape is an error even where the key is optional.
    auto read = [&](const char* key, cv::Mat* m, bool required, bool* found) {
      const bool ok = readCvMat(fs, key, m, &why);
      if (found) *found = ok;
      if (!why.empty()) return fail(error, path + ": " + key + ": " + why);
      if (!ok && required) return fail(error, path + ": " + key + ": missing");
      return true;
    };
    bool has_r1 = false, has_r2 = false, has_p1 = false, has_p2 = false;
    if (!read("M1", &m1, true, nullptr) || !read("M2", &m2, true, nullptr) ||
        !read("R", &r, true, nullptr) || !read("T", &t, true, nullptr) ||
        !read("D1", &d1, false, nullptr) || !read("D2", &d2, false, nullptr) ||
        !read("R1", &r1, false, &has_r1) || !read("R2", &r2, false, &has_r2) ||
        !read("P1", &p1, false, &has_p1) || !read("P2", &p2, false, &has_p2)) {
      return false;
    }
    if (!matToMatx33(m1, &s.left.K))
      return fail(error, path + ": M1: must be 3x3, got " + sizeString(m1));
    if (!matToMatx33(m2, &s.right.K))
      return fail(error, path + ": M2: must be 3x3, got " + sizeString(m2));
    if (!matToMatx33(r, &s.R_right_left))
      return fail(error, path + ": R: must be 3x3, got " + sizeString(r));
    if (t.total() != 3)
      return fail(error, path + ": T: must have 3 elements, got " + sizeString(t));
    for (int i = 0; i < 3; ++i) s.T_right_left[i] = t.at<double>(i) * translation_scale;
    s.has_extrinsics = true;
    for (int k = 0; k < 2; ++k) {
      const cv::Mat& d = k == 0 ? d1 : d2;
      CameraCalibration& cam = k == 0 ? s.left : s.right;
      if (!d.empty() && d.rows != 1 && d.cols != 1) {
        return fail(error,
                    path + (k == 0 ? ": D1" : ": D2") + ": must be a vector, got " + sizeString(d));
      }
      cam.D.clear();
      // (An empty cv::Mat's iterators divide by its zero element count: do not touch them.)
      if (!d.empty()) cam.D.assign(d.begin<double>(), d.end<double>());
      cam.distortion_model = modelForCount(cam.D.size());
    }
    if (has_r1 != has_r2 || has_p1 != has_p2 || has_r1 != has_p1) {
      return fail(error, path + ": R1 R2 P1 P2: give all four or none");
    }
    if (has_p1) {
      if (!matToMatx33(r1, &s.left.R))
        return fail(error, path + ": R1: must be 3x3, got " + sizeString(r1));
      if (!matToMatx33(r2, &s.right.R))
        return fail(error, path + ": R2: must be 3x3, got " + sizeString(r2));
      if (!matToMatx34(p1, &s.left.P))
        return fail(error, path + ": P1: must be 3x4, got " + sizeString(p1));
      if (!matToMatx34(p2, &s.right.P))
        return fail(error, path + ": P2: must be 3x4, got " + sizeString(p2));
      s.right.P(0, 3) *= translation_scale;
      s.right.P(1, 3) *= translation_scale;
      s.right.P(2, 3) *= translation_scale;
    }
    // Image size under the names seen in the wild; 0 = from the first images.
    int w = 0, h = 0;
    if (!fs["image_width"].empty()) {
      w = int(fs["image_width"]);
      h = int(fs["image_height"]);
    } else if (!fs["width"].empty()) {
      w = int(fs["width"]);
      h = int(fs["height"]);
    } else {
      for (const char* key : {"image_size", "imageSize"}) {
        cv::FileNode n = fs[key];
        if (n.empty()) continue;
        if (n.isSeq() && n.size() == 2) {
          w = int(n[0]);
          h = int(n[1]);
        } else {
          const std::string bad = checkMatrixNode(n);
          if (!bad.empty()) return fail(error, path + ": " + key + ": " + bad);
          cv::Mat sz;
          n >> sz;
          if (sz.total() == 2) {
            sz.convertTo(sz, CV_64F);
            w = int(sz.at<double>(0));
            h = int(sz.at<double>(1));
          }
        }
      }
    }
    s.left.width = s.right.width = w;
    s.left.height = s.right.height = h;
  } catch (const std::exception& ex) {
    return fail(error, path + ": " + ex.what());
  }
  if (!finish(s, path, error)) return false;
  out = s;
  return true;
}

bool loadStereoCalibration(const std::string& spec, StereoCalibration& out, std::string* error) {
  const size_t comma = spec.find(',');
  if (comma != std::string::npos) {
    return loadStereoCameraInfoYaml(spec.substr(0, comma), spec.substr(comma + 1), out, error);
  }
  return loadOpenCvStereoYaml(spec, out, error);
}

bool loadOpenCvXmlMatrix(const std::string& path, cv::Mat& out, std::string* error) {
  std::string text;
  if (!readFile(path, &text)) return fail(error, path + ": cannot read");
  auto block = [&](const std::string& tag, std::string* content) {
    const size_t a = text.find("<" + tag + ">");
    const size_t b = text.find("</" + tag + ">");
    if (a == std::string::npos || b == std::string::npos || b < a) return false;
    *content = text.substr(a + tag.size() + 2, b - a - tag.size() - 2);
    return true;
  };
  std::string rows_s, cols_s, data_s;
  if (!block("rows", &rows_s)) return fail(error, path + ": <rows> block missing");
  if (!block("cols", &cols_s)) return fail(error, path + ": <cols> block missing");
  if (!block("data", &data_s)) return fail(error, path + ": <data> block missing");
  int rows = 0, cols = 0;
  try {
    rows = std::stoi(rows_s);
    cols = std::stoi(cols_s);
  } catch (const std::exception&) {
    return fail(error, path + ": <rows>/<cols> are not integers");
  }
  if (rows <= 0 || cols <= 0) return fail(error, path + ": <rows>/<cols> must be > 0");
  std::istringstream is(data_s);
  std::vector<double> v;
  std::string tok;
  while (is >> tok) {
    try {
      v.push_back(std::stod(tok));
    } catch (const std::exception&) {
      return fail(error, path + ": <data>: not a number: '" + tok + "'");
    }
  }
  if (int(v.size()) != rows * cols) {
    return fail(error, path + ": <data> has " + std::to_string(v.size()) +
                           " values, rows x cols = " + std::to_string(rows * cols));
  }
  out = cv::Mat(rows, cols, CV_64F);
  std::copy(v.begin(), v.end(), out.begin<double>());
  return true;
}

bool loadSksurgeryXmlCalibration(const std::string& dir, int width, int height,
                                 StereoCalibration& out, std::string* error) {
  cv::Mat kl, dl, kr, dr, r, t;
  if (!loadOpenCvXmlMatrix(joinPath(dir, "calib.left.intrinsic.xml"), kl, error)) return false;
  if (!loadOpenCvXmlMatrix(joinPath(dir, "calib.left.distortion.xml"), dl, error)) return false;
  if (!loadOpenCvXmlMatrix(joinPath(dir, "calib.right.intrinsic.xml"), kr, error)) return false;
  if (!loadOpenCvXmlMatrix(joinPath(dir, "calib.right.distortion.xml"), dr, error)) return false;
  if (!loadOpenCvXmlMatrix(joinPath(dir, "calib.r2l.rotation.xml"), r, error)) return false;
  if (!loadOpenCvXmlMatrix(joinPath(dir, "calib.r2l.translation.xml"), t, error)) return false;
  StereoCalibration s;
  if (!matToMatx33(kl, &s.left.K)) return fail(error, dir + ": left intrinsic: must be 3x3");
  if (!matToMatx33(kr, &s.right.K)) return fail(error, dir + ": right intrinsic: must be 3x3");
  if (!matToMatx33(r, &s.R_right_left)) return fail(error, dir + ": rotation: must be 3x3");
  if (t.total() != 3) return fail(error, dir + ": translation: must have 3 values");
  for (int i = 0; i < 3; ++i) s.T_right_left[i] = t.at<double>(i) * 1e-3;  // mm -> m
  s.has_extrinsics = true;
  if (!dl.empty()) s.left.D.assign(dl.begin<double>(), dl.end<double>());
  if (!dr.empty()) s.right.D.assign(dr.begin<double>(), dr.end<double>());
  s.left.distortion_model = modelForCount(s.left.D.size());
  s.right.distortion_model = modelForCount(s.right.D.size());
  s.left.width = s.right.width = width;
  s.left.height = s.right.height = height;
  if (!finish(s, dir, error)) return false;
  out = s;
  return true;
}

bool loadTextStereoCalibration(const std::string& dir, int width, int height,
                               StereoCalibration& out, std::string* error) {
  std::vector<double> kl, kr, dl, dr, l2r;
  const std::string p_kl = joinPath(dir, "calib.left.intrinsic.txt");
  const std::string p_kr = joinPath(dir, "calib.right.intrinsic.txt");
  const std::string p_l2r = joinPath(dir, "calib.l2r.4x4");
  if (!readNumbers(p_kl, &kl, error) || !readNumbers(p_kr, &kr, error) ||
      !readNumbers(p_l2r, &l2r, error)) {
    return false;
  }
  if (!readNumbers(joinPath(dir, "calib.left.distortion.txt"), &dl, error)) dl.clear();
  if (!readNumbers(joinPath(dir, "calib.right.distortion.txt"), &dr, error)) dr.clear();
  if (error) error->clear();
  if (kl.size() != 9)
    return fail(error, p_kl + ": must hold 9 values (3x3 K), got " + std::to_string(kl.size()));
  if (kr.size() != 9)
    return fail(error, p_kr + ": must hold 9 values (3x3 K), got " + std::to_string(kr.size()));
  if (l2r.size() != 16)
    return fail(error, p_l2r + ": must hold 16 values (4x4), got " + std::to_string(l2r.size()));
  StereoCalibration s;
  s.left.K = toMatx<3, 3>(kl);
  s.right.K = toMatx<3, 3>(kr);
  s.left.D = dl;
  s.right.D = dr;
  s.left.distortion_model = modelForCount(dl.size());
  s.right.distortion_model = modelForCount(dr.size());
  for (int rr = 0; rr < 3; ++rr) {
    for (int cc = 0; cc < 3; ++cc) s.R_right_left(rr, cc) = l2r[rr * 4 + cc];
    s.T_right_left[rr] = l2r[rr * 4 + 3] * 1e-3;  // mm -> m
  }
  // The file stores the rotation to 6 decimals; re-orthonormalise so that validate() and
  // cv::stereoRectify see a proper rotation.
  cv::Mat w, u, vt;
  cv::SVD::compute(cv::Mat(s.R_right_left), w, u, vt);
  cv::Mat rn = u * vt;
  matToMatx33(rn, &s.R_right_left);
  s.has_extrinsics = true;
  s.left.width = s.right.width = width;
  s.left.height = s.right.height = height;
  if (!finish(s, dir, error)) return false;
  out = s;
  return true;
}

}  // namespace endo_stereo
