/* Occluder meshes from files, through the Open Asset Import Library
 * (Assimp, Debian's libassimp-dev): OBJ, PLY, glTF, FBX, STL, Collada and
 * the rest of what a studio exports a head or a body in. Polygons are
 * triangulated, node transforms applied, normals made where missing; points
 * and lines are dropped. The counts Assimp returns are checked again before
 * anything is allocated from them. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "hfrender.h"

#ifdef HR_HAVE_ASSIMP
#include <assimp/cimport.h>
#include <assimp/postprocess.h>
#include <assimp/scene.h>

int hfr_mesh_load(const char *path, hfr_mesh *out, char *err, size_t errlen) {
  if (!path || !out) return HF_EINVAL;
  memset(out, 0, sizeof *out);
  const struct aiScene *sc =
      aiImportFile(path, aiProcess_Triangulate | aiProcess_PreTransformVertices |
                             aiProcess_GenSmoothNormals | aiProcess_SortByPType |
                             aiProcess_JoinIdenticalVertices);
  if (!sc) {
    if (err) snprintf(err, errlen, "%s: %s", path, aiGetErrorString());
    return HF_EFORMAT;
  }
  int rc = HF_OK;
  uint64_t tris = 0;
  for (unsigned m = 0; m < sc->mNumMeshes; m++) {
    const struct aiMesh *me = sc->mMeshes[m];
    if (!me || !me->mVertices || !me->mFaces) continue;
    for (unsigned f = 0; f < me->mNumFaces; f++) tris += me->mFaces[f].mNumIndices == 3;
  }
  if (tris == 0) {
    if (err) snprintf(err, errlen, "%s: no triangles (a mesh of faces is needed)", path);
    rc = HF_EFORMAT;
  } else if (tris > HFR_MESH_MAX_TRIANGLES) {
    if (err)
      snprintf(err, errlen, "%s: %llu triangles, more than the %u supported: decimate it",
               path, (unsigned long long)tris, HFR_MESH_MAX_TRIANGLES);
    rc = HF_ERANGE;
  }
  if (rc == HF_OK && !(out->v = malloc(sizeof(float) * 18 * (size_t)tris))) rc = HF_ENOMEM;
  size_t k = 0;
  for (unsigned m = 0; rc == HF_OK && m < sc->mNumMeshes; m++) {
    const struct aiMesh *me = sc->mMeshes[m];
    if (!me || !me->mVertices || !me->mFaces) continue;
    for (unsigned f = 0; rc == HF_OK && f < me->mNumFaces; f++) {
      const struct aiFace *fc = &me->mFaces[f];
      if (fc->mNumIndices != 3) continue;
      for (int c = 0; c < 3; c++) {
        unsigned i = fc->mIndices[c];
        if (i >= me->mNumVertices) {
          if (err) snprintf(err, errlen, "%s: a face indexes past its mesh's vertices", path);
          rc = HF_EFORMAT;
          break;
        }
        float *o = out->v + 6 * k++;
        o[0] = me->mVertices[i].x, o[1] = me->mVertices[i].y, o[2] = me->mVertices[i].z;
        float n[3] = {0, 0, 0};
        if (me->mNormals) n[0] = me->mNormals[i].x, n[1] = me->mNormals[i].y, n[2] = me->mNormals[i].z;
        float l = sqrtf(n[0] * n[0] + n[1] * n[1] + n[2] * n[2]);
        for (int a = 0; a < 3; a++) o[3 + a] = l > 0 && isfinite(l) ? n[a] / l : 0;
        if (!isfinite(o[0]) || !isfinite(o[1]) || !isfinite(o[2])) {
          if (err) snprintf(err, errlen, "%s: non-finite vertex position", path);
          rc = HF_EFORMAT;
          break;
        }
      }
    }
  }
  aiReleaseImport(sc);
  if (rc != HF_OK) {
    hfr_mesh_free(out);
    return rc;
  }
  out->vertices = (uint32_t)k;
  return HF_OK;
}

#else

int hfr_mesh_load(const char *path, hfr_mesh *out, char *err, size_t errlen) {
  if (out) memset(out, 0, sizeof *out);
  if (err)
    snprintf(err, errlen, "%s: this build reads no mesh files (built without Assimp: install "
             "libassimp-dev and rebuild), use --occluder fit", path ? path : "mesh");
  return HF_EUNSUPPORTED;
}

#endif
