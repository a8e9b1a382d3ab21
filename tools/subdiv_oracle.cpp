// OpenSubdiv reference limit points for strata's subdivision tests (src/render/subdiv.rs).
//
// Built and run by tools/make_subdiv_fixtures.sh against Debian's libosd-dev (OpenSubdiv 3.5):
// each case is refined uniformly with Far::TopologyRefiner, USD's options (Catmull-Clark,
// uniform creasing, faceVaryingLinearInterpolation all), to a level past which every
// semi-sharp feature has decayed, and then projected with PrimvarRefiner::Limit. The limits of
// the level-2 vertices (followed to their descendants) are printed with each case's input and
// its visible face count at level 2.
#include <opensubdiv/far/primvarRefiner.h>
#include <opensubdiv/far/topologyDescriptor.h>
#include <opensubdiv/far/topologyRefinerFactory.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <string>
#include <vector>

using namespace OpenSubdiv;

struct Point {
    double p[3];
    void Clear() { p[0] = p[1] = p[2] = 0; }
    void AddWithWeight(Point const& s, double w) {
        for (int k = 0; k < 3; ++k) p[k] += w * s.p[k];
    }
};

struct Case {
    std::string name;
    std::string boundary;  // none | edgeOnly | edgeAndCorner
    int level;
    std::vector<Point> points;
    std::vector<int> counts, indices;
    std::vector<int> creaseEdges;  // pairs
    std::vector<float> creaseSharpness;
    std::vector<int> corners;
    std::vector<float> cornerSharpness;
};

// The limit points of the vertices of refinement level `out`, evaluated by refining to `level`
// (each vertex followed to its descendant there) and projecting that level; and the number of
// faces at `out` that are not holes.
static std::vector<Point> limits(Case const& c, int level, int out, int* visible) {
    Sdc::Options options;
    options.SetCreasingMethod(Sdc::Options::CREASE_UNIFORM);
    options.SetFVarLinearInterpolation(Sdc::Options::FVAR_LINEAR_ALL);
    if (c.boundary == "none") options.SetVtxBoundaryInterpolation(Sdc::Options::VTX_BOUNDARY_NONE);
    else if (c.boundary == "edgeOnly") options.SetVtxBoundaryInterpolation(Sdc::Options::VTX_BOUNDARY_EDGE_ONLY);
    else options.SetVtxBoundaryInterpolation(Sdc::Options::VTX_BOUNDARY_EDGE_AND_CORNER);

    Far::TopologyDescriptor desc;
    desc.numVertices = (int)c.points.size();
    desc.numFaces = (int)c.counts.size();
    desc.numVertsPerFace = c.counts.data();
    desc.vertIndicesPerFace = c.indices.data();
    desc.numCreases = (int)c.creaseSharpness.size();
    desc.creaseVertexIndexPairs = c.creaseEdges.data();
    desc.creaseWeights = c.creaseSharpness.data();
    desc.numCorners = (int)c.cornerSharpness.size();
    desc.cornerVertexIndices = c.corners.data();
    desc.cornerWeights = c.cornerSharpness.data();

    typedef Far::TopologyRefinerFactory<Far::TopologyDescriptor> Factory;
    Far::TopologyRefiner* refiner = Factory::Create(desc, Factory::Options(Sdc::SCHEME_CATMARK, options));
    Far::TopologyRefiner::UniformOptions uniform(level);
    uniform.fullTopologyInLastLevel = true;  // Limit() needs the last level's neighbourhoods
    refiner->RefineUniform(uniform);

    std::vector<Point> verts(refiner->GetNumVerticesTotal());
    std::copy(c.points.begin(), c.points.end(), verts.begin());
    Far::PrimvarRefinerReal<double> primvar(*refiner);
    Point* src = verts.data();
    for (int l = 1; l <= level; ++l) {
        Point* dst = src + refiner->GetLevel(l - 1).GetNumVertices();
        primvar.Interpolate(l, src, dst);
        src = dst;
    }
    std::vector<Point> limit(refiner->GetLevel(level).GetNumVertices());
    primvar.Limit(src, limit);

    Far::TopologyLevel const& outLevel = refiner->GetLevel(out);
    *visible = 0;
    for (int f = 0; f < outLevel.GetNumFaces(); ++f) *visible += !outLevel.IsFaceHole(f);
    std::vector<Point> result;
    for (int v = 0; v < outLevel.GetNumVertices(); ++v) {
        int descendant = v;
        for (int l = out; l < level; ++l) descendant = refiner->GetLevel(l).GetVertexChildVertex(descendant);
        result.push_back(limit[descendant]);
    }
    delete refiner;
    return result;
}

// Prints the case and the limit points of its level-2 vertices, refined to `c.level`; the
// tolerance is how far they still move from one level less (OpenSubdiv's limit at a dart is an
// estimate that improves with the level; elsewhere it is exact once sharpness has decayed).
static void run(Case const& c) {
    const int out = 2;
    int visible = 0, coarserVisible = 0;
    std::vector<Point> limit = limits(c, c.level, out, &visible);
    std::vector<Point> coarser = limits(c, c.level - 1, out, &coarserVisible);
    double tolerance = 0;
    for (size_t i = 0; i < limit.size(); ++i) {
        double d = 0;
        for (int k = 0; k < 3; ++k) d += (limit[i].p[k] - coarser[i].p[k]) * (limit[i].p[k] - coarser[i].p[k]);
        tolerance = std::max(tolerance, std::sqrt(d));
    }
    tolerance += 1e-12;

    printf("case %s\nboundary %s\nlevel %d\npoints %zu\n", c.name.c_str(), c.boundary.c_str(), out, c.points.size());
    for (Point const& p : c.points) printf("%.17g %.17g %.17g\n", p.p[0], p.p[1], p.p[2]);
    printf("faces %zu\n", c.counts.size());
    for (size_t f = 0, o = 0; f < c.counts.size(); o += c.counts[f], ++f) {
        printf("%d", c.counts[f]);
        for (int k = 0; k < c.counts[f]; ++k) printf(" %d", c.indices[o + k]);
        printf("\n");
    }
    printf("creases %zu\n", c.creaseSharpness.size());
    for (size_t e = 0; e < c.creaseSharpness.size(); ++e)
        printf("%d %d %.9g\n", c.creaseEdges[2 * e], c.creaseEdges[2 * e + 1], c.creaseSharpness[e]);
    printf("corners %zu\n", c.cornerSharpness.size());
    for (size_t v = 0; v < c.cornerSharpness.size(); ++v) printf("%d %.9g\n", c.corners[v], c.cornerSharpness[v]);
    printf("limit %zu\n", limit.size());
    for (Point const& p : limit) printf("%.17g %.17g %.17g\n", p.p[0], p.p[1], p.p[2]);
    printf("tolerance %.3g\nvisible_faces %d\nend\n", tolerance, visible);
}

static Case cube(std::string name, int level) {
    Case c;
    c.name = name;
    c.boundary = "edgeAndCorner";
    c.level = level;
    for (int i = 0; i < 8; ++i)
        c.points.push_back({{(i & 1) * 2.0 - 1, ((i >> 1) & 1) * 2.0 - 1, ((i >> 2) & 1) * 2.0 - 1}});
    int faces[6][4] = {{0, 2, 3, 1}, {4, 5, 7, 6}, {0, 1, 5, 4}, {2, 6, 7, 3}, {0, 4, 6, 2}, {1, 3, 7, 5}};
    for (auto& f : faces) {
        c.counts.push_back(4);
        c.indices.insert(c.indices.end(), f, f + 4);
    }
    return c;
}

static void crease(Case& c, int a, int b, float s) {
    c.creaseEdges.push_back(a);
    c.creaseEdges.push_back(b);
    c.creaseSharpness.push_back(s);
}

// A 3x3-quad open grid with a bumpy height, so boundary rules show.
static Case grid(std::string name, std::string boundary, int level) {
    Case c;
    c.name = name;
    c.boundary = boundary;
    c.level = level;
    for (int j = 0; j < 4; ++j)
        for (int i = 0; i < 4; ++i)
            c.points.push_back({{double(i), double(j), std::sin(1.3 * i + 0.7 * j)}});
    for (int j = 0; j < 3; ++j)
        for (int i = 0; i < 3; ++i) {
            int v = 4 * j + i;
            int f[4] = {v, v + 1, v + 5, v + 4};
            c.counts.push_back(4);
            c.indices.insert(c.indices.end(), f, f + 4);
        }
    return c;
}

int main() {
    run(cube("cube_smooth", 3));
    {
        Case c = cube("cube_all_edges_infinitely_sharp", 3);
        int edges[12][2] = {{0, 1}, {2, 3}, {4, 5}, {6, 7}, {0, 2}, {1, 3},
                            {4, 6}, {5, 7}, {0, 4}, {1, 5}, {2, 6}, {3, 7}};
        for (auto& e : edges) crease(c, e[0], e[1], 10.0f);
        run(c);
    }
    // The top face's four edges (a closed crease loop) at several sharpnesses.
    float ring[] = {0.5f, 1.0f, 1.5f, 2.5f};
    for (float s : ring) {
        char name[64];
        snprintf(name, sizeof name, "cube_top_loop_sharpness_%g", s);
        Case c = cube(name, std::max(3, (int)std::ceil(s) + 2));
        crease(c, 4, 5, s);
        crease(c, 5, 7, s);
        crease(c, 7, 6, s);
        crease(c, 6, 4, s);
        run(c);
    }
    {
        // An open chain with per-edge sharpness: 3.7 needs four levels to decay.
        Case c = cube("cube_chain_per_edge", 8);
        crease(c, 0, 1, 3.7f);
        crease(c, 1, 3, 0.5f);
        crease(c, 3, 2, 10.0f);
        run(c);
    }
    {
        Case c = cube("cube_dart", 8);
        crease(c, 0, 1, 10.0f);
        run(c);
    }
    {
        Case c = cube("cube_corner_infinite", 3);
        c.corners.push_back(0);
        c.cornerSharpness.push_back(10.0f);
        run(c);
    }
    {
        Case c = cube("cube_corner_semi_sharp_with_crease", 4);
        c.corners.push_back(0);
        c.cornerSharpness.push_back(1.5f);
        c.corners.push_back(7);
        c.cornerSharpness.push_back(0.25f);
        crease(c, 7, 6, 2.0f);
        run(c);
    }
    run(grid("grid_edge_and_corner", "edgeAndCorner", 3));
    run(grid("grid_edge_only", "edgeOnly", 3));
    run(grid("grid_none", "none", 3));
    {
        Case c = grid("grid_edge_only_crease", "edgeOnly", 4);
        crease(c, 4, 5, 2.0f);
        crease(c, 5, 6, 2.0f);
        crease(c, 6, 7, 2.0f);
        run(c);
    }
    {
        Case c = grid("grid_none_one_sharp_boundary", "none", 3);
        // Boundary edges authored infinitely sharp keep their faces under `none`.
        crease(c, 0, 1, 10.0f);
        crease(c, 1, 2, 10.0f);
        crease(c, 2, 3, 10.0f);
        run(c);
    }
    {
        // A square pyramid: triangles, a quad, a semi-sharp base loop and apex corner.
        Case c;
        c.name = "pyramid_semi_sharp";
        c.boundary = "edgeAndCorner";
        c.level = 4;
        c.points = {{{-1, -1, 0}}, {{1, -1, 0}}, {{1, 1, 0}}, {{-1, 1, 0}}, {{0.2, 0.1, 1.5}}};
        c.counts = {4, 3, 3, 3, 3};
        c.indices = {0, 3, 2, 1, 0, 1, 4, 1, 2, 4, 2, 3, 4, 3, 0, 4};
        crease(c, 0, 1, 1.5f);
        crease(c, 1, 2, 1.5f);
        crease(c, 2, 3, 1.5f);
        crease(c, 3, 0, 0.75f);
        c.corners.push_back(4);
        c.cornerSharpness.push_back(0.5f);
        run(c);
    }
    return 0;
}
