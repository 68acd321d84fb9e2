// image_transport "compressed" plugins (JPEG / PNG in sensor_msgs/CompressedImage), wire-compatible
// with compressed_image_transport: topic <base>/compressed, format "<encoding>; <jpeg|png>
// compressed <encoding>". Debian packages image_transport with the raw transport only, so without
// these a bag recorded with compressed images (the usual way to record endoscope video) could not
// be played into the nodelet. Parameters, as compressed_image_transport reads them, under
// <base>/compressed: format (jpeg | png, default jpeg), jpeg_quality (1..100, default 95),
// png_level (0..9, default 3). Where compressed_image_transport is installed too, pluginlib sees two
// classes with the same lookup name and uses one of them; both speak the same format.
#include <algorithm>
#include <string>
#include <vector>

#include <image_transport/simple_publisher_plugin.h>
#include <image_transport/simple_subscriber_plugin.h>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <pluginlib/class_list_macros.hpp>
#include <sensor_msgs/CompressedImage.h>
#include <sensor_msgs/image_encodings.h>

#include "endo_stereo/ros/conversions.hpp"

namespace endo_stereo {

namespace enc = sensor_msgs::image_encodings;

class CompressedPublisher
    : public image_transport::SimplePublisherPlugin<sensor_msgs::CompressedImage> {
 public:
  std::string getTransportName() const override { return "compressed"; }

 protected:
  void publish(const sensor_msgs::Image& message, const PublishFn& publish_fn) const override {
    std::string format = "jpeg";
    int jpeg_quality = 95, png_level = 3;
    nh().param("format", format, format);
    nh().param("jpeg_quality", jpeg_quality, jpeg_quality);
    nh().param("png_level", png_level, png_level);
    cv::Mat mat;
    std::string error;
    if (message.encoding != enc::MONO8 && message.encoding != enc::MONO16 &&
        message.encoding != enc::BGR8 && message.encoding != enc::RGB8 &&
        message.encoding != enc::BGRA8 && message.encoding != enc::RGBA8) {
      ROS_ERROR_THROTTLE(5.0, "compressed transport: encoding '%s' is not supported "
                         "(mono8, mono16, bgr8, rgb8, bgra8, rgba8)", message.encoding.c_str());
      return;
    }
    if (!ros_conv::imageToMat(message, mat, &error)) {
      ROS_ERROR_THROTTLE(5.0, "compressed transport: %s", error.c_str());
      return;
    }
    // JPEG holds 8-bit gray or colour only.
    const bool png = format == "png" || message.encoding == enc::MONO16 ||
                     message.encoding == enc::BGRA8 || message.encoding == enc::RGBA8;
    if (message.encoding == enc::RGB8) cv::cvtColor(mat, mat, cv::COLOR_RGB2BGR);
    if (message.encoding == enc::RGBA8) cv::cvtColor(mat, mat, cv::COLOR_RGBA2BGRA);
    std::vector<int> options;
    if (png) {
      options = {cv::IMWRITE_PNG_COMPRESSION, std::clamp(png_level, 0, 9)};
    } else {
      options = {cv::IMWRITE_JPEG_QUALITY, std::clamp(jpeg_quality, 1, 100)};
    }
    sensor_msgs::CompressedImage out;
    out.header = message.header;
    const std::string kind = png ? "png" : "jpeg";
    out.format = message.encoding + "; " + kind + " compressed " +
                 (mat.channels() == 1 ? std::string() : message.encoding);
    if (!cv::imencode(png ? ".png" : ".jpg", mat, out.data, options)) {
      ROS_ERROR_THROTTLE(5.0, "compressed transport: %s encoding failed", kind.c_str());
      return;
    }
    publish_fn(out);
  }
};

class CompressedSubscriber
    : public image_transport::SimpleSubscriberPlugin<sensor_msgs::CompressedImage> {
 public:
  std::string getTransportName() const override { return "compressed"; }

 protected:
  void internalCallback(const sensor_msgs::CompressedImageConstPtr& message,
                        const Callback& user_cb) override {
    const cv::Mat decoded = cv::imdecode(message->data, cv::IMREAD_UNCHANGED);
    if (decoded.empty()) {
      ROS_ERROR_THROTTLE(5.0, "compressed transport: cannot decode an image (format '%s')",
                         message->format.c_str());
      return;
    }
    // The original encoding is the text before ';' (older publishers wrote only "jpeg").
    std::string encoding = message->format.substr(0, message->format.find(';'));
    const bool known = encoding == enc::MONO8 || encoding == enc::MONO16 ||
                       encoding == enc::BGR8 || encoding == enc::RGB8 ||
                       encoding == enc::BGRA8 || encoding == enc::RGBA8;
    if (!known) encoding = decoded.channels() == 1 ? enc::MONO8 : enc::BGR8;
    cv::Mat mat = decoded;
    if (encoding == enc::RGB8 && mat.channels() == 3) cv::cvtColor(mat, mat, cv::COLOR_BGR2RGB);
    if (encoding == enc::RGBA8 && mat.channels() == 4) cv::cvtColor(mat, mat, cv::COLOR_BGRA2RGBA);
    if (mat.channels() == 1 && (encoding == enc::BGR8 || encoding == enc::RGB8)) {
      encoding = enc::MONO8;
    }
    try {
      user_cb(boost::make_shared<sensor_msgs::Image>(
          ros_conv::matToImage(mat, encoding, message->header)));
    } catch (const std::exception& ex) {
      ROS_ERROR_THROTTLE(5.0, "compressed transport: decoded image does not fit '%s': %s",
                         encoding.c_str(), ex.what());
    }
  }
};

}  // namespace endo_stereo

PLUGINLIB_EXPORT_CLASS(endo_stereo::CompressedPublisher, image_transport::PublisherPlugin)
PLUGINLIB_EXPORT_CLASS(endo_stereo::CompressedSubscriber, image_transport::SubscriberPlugin)
