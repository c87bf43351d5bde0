// `voxelastic convert --xml`: the Slicer Execution Model description that makes convert a 3D
// Slicer CLI module (issue #29). Checked the way Slicer reads it: well-formed XML (xmllint, a
// hard requirement: libxml2-utils, scripts/install-deps.sh), then the rules of Slicer's own
// reader, ModuleDescriptionParser (SlicerExecutionModel), restated here: the elements and
// attributes it knows, a <name> and <longflag> of letters, digits and '_' only (it refuses the
// module otherwise), a one-letter <flag>, a flag or an index but not both. Slicer's
// ModuleDescription.xsd is no check: libxml2 cannot compile it (an attribute after
// complexContent), and repaired it still refuses what the parser takes (a <longflag> on an
// <image>, more than one <element>), Slicer's own test descriptions among them. Then every
// option of `convert --help` described once, and a run with the described defaults and flags,
// as Slicer starts it (`--fill_holes`: '_' for '-'), that converts a phantom.
#include <gtest/gtest.h>
#include <unistd.h>
#include <vtkNew.h>
#include <vtkSmartPointer.h>
#include <vtkXMLDataElement.h>
#include <vtkXMLUtilities.h>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <map>
#include <regex>
#include <set>
#include <string>
#include <vector>

#include "base/version.h"
#include "convert/phantom.h"
#include "io/volume_io.h"
#include "support/run_binary.h"
#include "util/exit_codes.h"

namespace fs = std::filesystem;
using vx::testing::RunResult;

namespace {

const fs::path kBinary = fs::path(VX_BINARY_DIR) / "apps" / "voxelastic" / "voxelastic";

class CliSlicerXml : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = fs::temp_directory_path() / ("vx_cli_slicer_xml_" + std::to_string(::getpid()) + "_" +
                                        ::testing::UnitTest::GetInstance()->current_test_info()->name());
    fs::remove_all(dir_);
    fs::create_directories(dir_);
  }
  void TearDown() override {
    if (!HasFailure()) fs::remove_all(dir_);
  }
  RunResult run(const std::string& args) const { return vx::testing::run_binary(kBinary, args, dir_, dir_); }
  fs::path dir_;
};

std::string trimmed(const char* s) {
  std::string t = s ? s : "";
  const auto a = t.find_first_not_of(" \t\r\n"), b = t.find_last_not_of(" \t\r\n");
  return a == std::string::npos ? std::string() : t.substr(a, b - a + 1);
}

/// The text of the child named `name` ("" when there is none).
std::string child_text(vtkXMLDataElement* e, const char* name) {
  vtkXMLDataElement* c = e->FindNestedElementWithName(name);
  return c ? trimmed(c->GetCharacterData()) : std::string();
}

int count_children(vtkXMLDataElement* e, const std::string& name) {
  int n = 0;
  for (int i = 0; i < e->GetNumberOfNestedElements(); ++i) n += name == e->GetNestedElement(i)->GetName();
  return n;
}

/// The long options `convert --help` lists (--name, without --help and --xml).
std::set<std::string> help_long_options(const std::string& help) {
  std::set<std::string> out;
  const std::regex opt(R"((^|[ ,])--([a-z][a-z0-9-]*))");
  for (auto it = std::sregex_iterator(help.begin(), help.end(), opt); it != std::sregex_iterator(); ++it) {
    const std::string name = (*it)[2];
    if (name != "help" && name != "xml") out.insert(name);
  }
  return out;
}

/// ModuleDescriptionParser's test for a <name> or <longflag> (after dropping leading '-'): a
/// letter or '_' first, then letters, digits and '_'.
bool slicer_variable(const std::string& s) { return std::regex_match(s, std::regex("[A-Za-z_][A-Za-z0-9_]*")); }

/// What ModuleDescriptionParser accepts inside a parameter, and the attributes of the kinds we
/// use (any other is an error there, and Slicer does not load the module).
const std::set<std::string> kParameterChildren = {"name",        "flag",        "longflag", "label",
                                                  "description", "default",     "channel",  "index",
                                                  "element",     "constraints", "reference"};
const std::map<std::string, std::set<std::string>> kAttributes = {
    {"image", {"type", "fileExtensions", "multiple", "hidden", "reference"}},
    {"geometry", {"type", "fileExtensions", "multiple", "aggregate", "reference"}},
    {"file", {"fileExtensions", "multiple"}},
    {"integer", {"hidden", "multiple"}},
    {"double", {"hidden", "multiple"}},
    {"float", {"hidden", "multiple"}},
    {"boolean", {"hidden"}},
    {"string", {"hidden", "multiple"}},
    {"string-enumeration", {"hidden"}}};
const std::set<std::string> kImageTypes = {"any",
                                           "scalar",
                                           "label",
                                           "tensor",
                                           "diffusion-weighted",
                                           "vector",
                                           "signal",
                                           "multichannel",
                                           "dynamic-contrast-enhanced"};

struct Parameter {
  std::string kind, name, longflag, flag, index, channel, default_value;
  std::vector<std::string> elements;
};

TEST_F(CliSlicerXml, ConvertDescribesItselfAsASlicerCliModule) {
  const RunResult r = run("convert --xml");
  ASSERT_EQ(r.code, vx::exit_code::ok) << r.err;
  EXPECT_EQ(r.err, "");
  ASSERT_EQ(r.out.rfind("<?xml version=\"1.0\"", 0), 0u) << r.out.substr(0, 80);
  const fs::path xml = dir_ / "convert.xml";
  std::ofstream(xml) << r.out;

  // well-formed, by libxml2 (a test dependency: it cannot pass without it)
  const fs::path xmllint = VX_XMLLINT;
  ASSERT_TRUE(fs::exists(xmllint)) << "xmllint was not found when configuring (" << xmllint
                                   << "): install libxml2-utils (scripts/install-deps.sh) and configure again";
  fs::create_directories(dir_ / "lint");
  const RunResult lint = vx::testing::run_binary(xmllint, "--noout '" + xml.string() + "'", dir_, dir_ / "lint");
  EXPECT_EQ(lint.code, 0) << lint.err;
  EXPECT_EQ(lint.err, "");

  // the module description: its header elements in the order the schema sets
  vtkSmartPointer<vtkXMLDataElement> root;
  root.TakeReference(vtkXMLUtilities::ReadElementFromFile(xml.c_str()));
  ASSERT_NE(root, nullptr) << "expat could not parse the description";
  ASSERT_STREQ(root->GetName(), "executable");
  const std::vector<std::string> header = {"category", "title",   "description", "version",
                                           "documentation-url", "license", "contributor"};
  ASSERT_GT(root->GetNumberOfNestedElements(), int(header.size()));
  for (std::size_t i = 0; i < header.size(); ++i)
    EXPECT_EQ(root->GetNestedElement(int(i))->GetName(), header[i]) << "element " << i;
  EXPECT_EQ(child_text(root, "version"), vx::kVersion);
  EXPECT_EQ(child_text(root, "title"), "voxelastic convert");
  EXPECT_EQ(child_text(root, "license"), "BSD-3-Clause");
  EXPECT_EQ(root->GetNumberOfAttributes(), 0);

  // the parameter groups (attribute: advanced) and their parameters
  const std::set<std::string> kinds = {"integer", "double", "float", "boolean", "string", "string-enumeration",
                                       "image", "geometry", "file"};
  std::vector<Parameter> params;
  std::set<std::string> names, longflags;
  int groups = 0;
  for (int g = int(header.size()); g < root->GetNumberOfNestedElements(); ++g) {
    vtkXMLDataElement* group = root->GetNestedElement(g);
    ASSERT_STREQ(group->GetName(), "parameters") << "after the header, only parameter groups";
    ++groups;
    for (int a = 0; a < group->GetNumberOfAttributes(); ++a)
      EXPECT_STREQ(group->GetAttributeName(a), "advanced") << "<parameters> takes no other attribute";
    if (const char* adv = group->GetAttribute("advanced")) {
      EXPECT_TRUE(std::string(adv) == "true" || std::string(adv) == "false") << adv;
    }
    EXPECT_NE(child_text(group, "label"), "") << "group " << groups << " has a label";
    for (int i = 0; i < group->GetNumberOfNestedElements(); ++i) {
      vtkXMLDataElement* e = group->GetNestedElement(i);
      const std::string kind = e->GetName();
      if (kind == "label" || kind == "description") continue;
      EXPECT_TRUE(kinds.count(kind)) << "unknown parameter type <" << kind << ">";
      for (int k = 0; k < e->GetNumberOfNestedElements(); ++k)
        EXPECT_TRUE(kParameterChildren.count(e->GetNestedElement(k)->GetName()))
            << "<" << kind << "> has a <" << e->GetNestedElement(k)->GetName() << ">, which Slicer refuses";
      for (int a = 0; a < e->GetNumberOfAttributes(); ++a) {
        const std::string attr = e->GetAttributeName(a), value = e->GetAttributeValue(a);
        const auto allowed = kAttributes.find(kind);
        EXPECT_TRUE(allowed != kAttributes.end() && allowed->second.count(attr))
            << "<" << kind << " " << attr << "=...>: not an attribute Slicer takes there";
        if (attr == "type" && kind == "image") {
          EXPECT_TRUE(kImageTypes.count(value)) << "image type " << value;
        }
        if (attr == "type" && kind == "geometry") {
          EXPECT_TRUE(value == "model" || value == "fiberbundle") << value;
        }
        if (attr == "multiple" || attr == "hidden") {
          EXPECT_TRUE(value == "true" || value == "false") << value;
        }
        if (attr == "fileExtensions") {
          EXPECT_TRUE(std::regex_match(value, std::regex(R"((\.[a-z]+)+)"))) << value;
        }
      }
      Parameter p{kind,
                  child_text(e, "name"),
                  child_text(e, "longflag"),
                  child_text(e, "flag"),
                  child_text(e, "index"),
                  child_text(e, "channel"),
                  child_text(e, "default"),
                  {}};
      for (int k = 0; k < e->GetNumberOfNestedElements(); ++k)
        if (std::string(e->GetNestedElement(k)->GetName()) == "element")
          p.elements.push_back(trimmed(e->GetNestedElement(k)->GetCharacterData()));
      // each parameter: a unique C-identifier name, a label, a description, one name of each kind
      EXPECT_TRUE(slicer_variable(p.name)) << "<name> '" << p.name << "'";
      EXPECT_TRUE(names.insert(p.name).second) << "two parameters named " << p.name;
      EXPECT_NE(child_text(e, "label"), "") << p.name;
      EXPECT_NE(child_text(e, "description"), "") << p.name;
      for (const char* once : {"name", "label", "description", "longflag", "flag", "index", "channel", "default"})
        EXPECT_LE(count_children(e, once), 1) << p.name << " has two <" << once << ">";
      // Slicer passes it by flag or by position, never both or neither
      EXPECT_NE(p.longflag.empty(), p.index.empty()) << p.name << ": a <longflag> or an <index>";
      if (!p.longflag.empty()) {
        // the parser drops leading '-' and refuses anything but letters, digits and '_'
        EXPECT_TRUE(slicer_variable(p.longflag)) << "<longflag>" << p.longflag << "</longflag>: Slicer refuses it";
        EXPECT_TRUE(longflags.insert(p.longflag).second) << "two --" << p.longflag;
      }
      if (!p.flag.empty()) {
        EXPECT_TRUE(std::regex_match(p.flag, std::regex("[A-Za-z]"))) << "<flag>" << p.flag << "</flag>: one letter";
        EXPECT_FALSE(p.longflag.empty()) << p.name << ": a <flag> beside its <longflag>";
      }
      if (!p.index.empty()) {
        EXPECT_TRUE(p.flag.empty()) << p.name << ": Slicer refuses a <flag> beside an <index>";
      }
      // a number's default inside its constraints, as the panel's slider holds it
      if (kind == "integer" || kind == "double" || kind == "float") {
        vtkXMLDataElement* c = e->FindNestedElementWithName("constraints");
        const double v = std::stod(p.default_value);
        if (kind == "integer") {
          EXPECT_EQ(p.default_value, std::to_string(std::lround(v))) << p.name;
        }
        if (c) {
          EXPECT_LE(std::stod(child_text(c, "minimum")), v) << p.name;
          EXPECT_GE(std::stod(child_text(c, "maximum")), v) << p.name;
          EXPECT_GT(std::stod(child_text(c, "step")), 0.0) << p.name;
          EXPECT_EQ(c->GetNumberOfNestedElements(), 3) << p.name << ": minimum, maximum, step";
        }
      }
      // files and data carry their direction
      if (kind == "image" || kind == "geometry" || kind == "file") {
        EXPECT_TRUE(p.channel == "input" || p.channel == "output") << p.name << ": <channel> " << p.channel;
      }
      if (kind == "string-enumeration") {
        EXPECT_GE(p.elements.size(), 2u) << p.name;
        EXPECT_NE(std::find(p.elements.begin(), p.elements.end(), p.default_value), p.elements.end())
            << p.name << ": the default is one of the elements";
      }
      if (kind == "boolean") {
        EXPECT_EQ(p.default_value, "false") << p.name << ": a flag is off by default";
      }
      params.push_back(p);
    }
  }
  EXPECT_GE(groups, 2);

  // the input volume is the one positional argument, the model an output
  const auto input = std::find_if(params.begin(), params.end(), [](const Parameter& p) { return p.index == "0"; });
  ASSERT_NE(input, params.end());
  EXPECT_EQ(input->kind, "image");
  EXPECT_EQ(input->channel, "input");
  EXPECT_EQ(std::count_if(params.begin(), params.end(), [](const Parameter& p) { return !p.index.empty(); }), 1);

  // every option of convert described, and nothing else (the flags with '_' for '-')
  const RunResult help = run("convert --help");
  ASSERT_EQ(help.code, 0);
  const std::set<std::string> options = help_long_options(help.out);
  EXPECT_GE(options.size(), 14u) << help.out;
  std::set<std::string> hyphenated;
  for (std::string f : longflags) {
    std::replace(f.begin(), f.end(), '_', '-');
    hyphenated.insert(f);
  }
  EXPECT_EQ(hyphenated, options);
  EXPECT_TRUE(longflags.count("fill_holes")) << "the flags Slicer passes: '_' for '-'";
}

TEST_F(CliSlicerXml, TheDescribedDefaultsConvertAPhantomAsSlicerWouldRunIt) {
  // Slicer runs the module with every non-empty value (the defaults unless the user changed
  // them), flags for the booleans that are on, then the positional arguments
  const RunResult r = run("convert --xml");
  ASSERT_EQ(r.code, 0) << r.err;
  vtkSmartPointer<vtkXMLDataElement> root;
  root.TakeReference(vtkXMLUtilities::ReadElementFromString(r.out.c_str()));
  ASSERT_NE(root, nullptr);
  std::string args;
  for (int g = 0; g < root->GetNumberOfNestedElements(); ++g) {
    vtkXMLDataElement* group = root->GetNestedElement(g);
    if (std::string(group->GetName()) != "parameters") continue;
    for (int i = 0; i < group->GetNumberOfNestedElements(); ++i) {
      vtkXMLDataElement* e = group->GetNestedElement(i);
      const std::string kind = e->GetName(), flag = child_text(e, "longflag"), value = child_text(e, "default");
      if (flag.empty() || kind == "geometry" || kind == "file") continue;  // outputs: given below
      if (kind == "boolean") {
        if (value == "true") args += " --" + flag;
      } else if (!value.empty()) {
        args += " --" + flag + " " + value;
      }
    }
  }
  vx::PhantomSettings ps;
  ps.name = "sphere";
  ps.size = 16;
  vx::PhantomShape shape;
  vx::write_volume(vx::make_phantom(ps, &shape), dir_ / "in.nrrd");
  ASSERT_NE(args.find("--max_level -1"), std::string::npos) << "Slicer's flags, '_' for '-': " << args;
  const RunResult c = run("convert" + args + " --output=model_slicer.vtu --stats stats.json in.nrrd");
  ASSERT_EQ(c.code, 0) << args << "\n" << c.err;
  EXPECT_TRUE(fs::exists(dir_ / "model_slicer.vtu"));  // a value keeps its '_'
  // the defaults are convert's own: the same model as without any option
  const RunResult plain = run("convert in.nrrd -o plain.vtu --stats plain.json");
  ASSERT_EQ(plain.code, 0) << plain.err;
  const auto elements = [&](const char* stats) {
    const std::string text = vx::testing::slurp(dir_ / stats);
    std::smatch m;
    return std::regex_search(text, m, std::regex(R"re("elements": ([0-9]+))re")) ? std::stoi(m[1]) : -1;
  };
  EXPECT_EQ(elements("stats.json"), elements("plain.json"));
  EXPECT_GT(elements("plain.json"), 0);
  // a value Slicer passes by an '_' flag takes effect as its '-' twin: level 0 only
  ASSERT_EQ(run("convert in.nrrd -o a.vtu --max_level 0 --stats level0_slicer.json").code, 0);
  ASSERT_EQ(run("convert in.nrrd -o b.vtu --max-level 0 --stats level0.json").code, 0);
  EXPECT_EQ(elements("level0_slicer.json"), elements("level0.json"));
  EXPECT_GT(elements("level0.json"), elements("plain.json"));
}

}  // namespace
