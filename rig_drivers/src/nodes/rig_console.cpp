// rig_console: the TrackHost-style text console. Typed commands go to every driver in ~hosts
// (default track_host and car_host) as service calls:
//   init | mode 1|2 | start | stop | reset | end | vers | para | help | quit
// Commands also run non-interactively: `rig_console init "mode 2" start` executes them in order
// and exits (status 1 if any failed). Parameters: config/drivers.yaml.
#include <ros/ros.h>

#include <iostream>
#include <sstream>
#include <string>
#include <vector>

#include "rig_msgs/Command.h"
#include "rig_msgs/Parameters.h"
#include "rig_msgs/SetMode.h"
#include "rig_msgs/Version.h"

namespace {

const char* kHelp =
    "commands: init             initialise (track: home to the far sensor)\n"
    "          mode 1|2         1 = continuous, 2 = step sequence\n"
    "          start | stop     start / stop a run\n"
    "          reset            clear a latched emergency stop or fault\n"
    "          end              end the run on every board, then leave the console\n"
    "          vers | para      version / parameter data of every component\n"
    "          help | quit";

class Console {
 public:
  explicit Console(std::vector<std::string> hosts) : hosts_(std::move(hosts)) {}

  /// Executes one typed line; false when a command failed (unknown command, board error).
  bool execute(const std::string& line, bool* quit) {
    std::istringstream in(line);
    std::vector<std::string> w;
    for (std::string s; in >> s;) w.push_back(s);
    if (w.empty()) return true;
    const std::string& c = w[0];
    if (c == "help" || c == "?") {
      std::cout << kHelp << std::endl;
      return true;
    }
    if (c == "quit" || c == "exit") {
      *quit = true;
      return true;
    }
    if (c == "mode") {
      if (w.size() != 2 || (w[1] != "1" && w[1] != "2")) {
        std::cout << "usage: mode 1|2 (1 = continuous, 2 = step sequence)" << std::endl;
        return false;
      }
      return forEachHost([&](const std::string& h) {
        rig_msgs::SetMode s;
        s.request.mode = static_cast<std::uint8_t>(std::stoi(w[1]));
        if (!ros::service::call(h + "/mode", s)) return report(h, false, "service call failed");
        return report(h, s.response.success, s.response.message);
      });
    }
    if (w.size() != 1) {
      std::cout << "'" << c << "' takes no argument (type help)" << std::endl;
      return false;
    }
    if (c == "vers") {
      std::cout << "rig_console 0.1.0" << std::endl;
      return forEachHost([&](const std::string& h) {
        rig_msgs::Version v;
        if (!ros::service::call(h + "/vers", v)) return report(h, false, "service call failed");
        for (std::size_t i = 0; i < v.response.components.size(); ++i)
          std::cout << "  " << v.response.components[i] << " "
                    << (i < v.response.versions.size() ? v.response.versions[i] : "?") << std::endl;
        std::cout << "  protocol " << int(v.response.protocol_version) << std::endl;
        return report(h, v.response.success, v.response.message);
      });
    }
    if (c == "para") {
      return forEachHost([&](const std::string& h) {
        rig_msgs::Parameters p;
        if (!ros::service::call(h + "/para", p)) return report(h, false, "service call failed");
        for (std::size_t i = 0; i < p.response.names.size(); ++i)
          std::cout << "  " << p.response.names[i] << " = " << p.response.values[i] << std::endl;
        return report(h, p.response.success, p.response.message);
      });
    }
    std::uint8_t code = 0;
    if (c == "init") code = rig_msgs::Command::Request::INIT;
    if (c == "start") code = rig_msgs::Command::Request::START;
    if (c == "stop") code = rig_msgs::Command::Request::STOP;
    if (c == "reset") code = rig_msgs::Command::Request::RESET;
    if (c == "end") code = rig_msgs::Command::Request::END;
    if (!code) {
      std::cout << "unknown command '" << c << "' (type help)" << std::endl;
      return false;
    }
    const bool ok = forEachHost([&](const std::string& h) {
      rig_msgs::Command cmd;
      cmd.request.command = code;
      if (!ros::service::call(h + "/command", cmd)) return report(h, false, "service call failed");
      return report(h, cmd.response.success, cmd.response.message);
    });
    if (c == "end") *quit = true;
    return ok;
  }

 private:
  template <class F>
  bool forEachHost(const F& f) {
    bool all = true, any = false;
    for (const auto& h : hosts_) {
      if (!ros::service::exists(h + "/command", false)) {
        std::cout << "  " << h << ": not running (skipped)" << std::endl;
        continue;
      }
      any = true;
      all = f(h) && all;
    }
    if (!any) std::cout << "no driver is running (~hosts)" << std::endl;
    return all && any;
  }
  static bool report(const std::string& host, bool ok, const std::string& msg) {
    std::cout << "  " << host << ": " << (ok ? "ok" : "FAILED") << " - " << msg << std::endl;
    return ok;
  }
  std::vector<std::string> hosts_;
};

}  // namespace

int main(int argc, char** argv) {
  ros::init(argc, argv, "rig_console", ros::init_options::AnonymousName);
  ros::NodeHandle pnh("~");
  std::vector<std::string> hosts;
  std::string hosts_text;  // also "a,b" or "[a,b]" (a _hosts:= command-line value is a string)
  if (!pnh.getParam("hosts", hosts) && pnh.getParam("hosts", hosts_text)) {
    for (char& c : hosts_text)
      if (c == ',' || c == '[' || c == ']') c = ' ';
    std::istringstream in(hosts_text);
    for (std::string h; in >> h;) hosts.push_back(h);
  }
  if (hosts.empty()) hosts = {"track_host", "car_host"};
  Console console(hosts);
  bool quit = false;
  if (argc > 1) {  // one-shot: each argument is one command line
    bool ok = true;
    for (int i = 1; i < argc && !quit; ++i) {
      std::cout << "> " << argv[i] << std::endl;
      ok = console.execute(argv[i], &quit) && ok;
    }
    return ok ? 0 : 1;
  }
  std::cout << "rig console (" << hosts.size() << " drivers). " << kHelp << std::endl;
  std::string line;
  while (!quit && ros::ok() && (std::cout << "rig> " << std::flush, std::getline(std::cin, line)))
    console.execute(line, &quit);
  return 0;
}
