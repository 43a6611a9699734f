// Validates Kubernetes manifests against the API schemas, offline.
//
//   node deploy/kubernetes/validate/validate.mjs FILE.yaml...
//
// Every document's apiVersion and kind pick its model from kubernetes-models
// (the Kubernetes OpenAPI schemas, compiled to validators) or, for
// monitoring.coreos.com, @kubernetes-models/prometheus-operator (the
// ServiceMonitor CRD's schema); the versions are pinned in package.json and
// package-lock.json and installed by deploy/debian/setup.sh. Like
// kubeconform without -strict, a field the schema does not know is not an
// error; wrong types, missing required fields and unknown kinds are.
//
// --expect-invalid FILE: exits 0 only when every document of FILE fails,
// which is how the test shows that the validator can fail.
import { readFileSync } from "node:fs";
import { parseAllDocuments } from "yaml";

function modulePath(apiVersion, kind) {
  const [group, version] = apiVersion.includes("/") ? apiVersion.split("/") : ["", apiVersion];
  if (group === "monitoring.coreos.com")
    return `@kubernetes-models/prometheus-operator/${group}/${version}/${kind}`;
  return `kubernetes-models/${group ? group + "/" : ""}${version}/${kind}`;
}

async function validate(doc) {
  if (!doc || typeof doc !== "object") return "not an object";
  const { apiVersion, kind } = doc;
  if (typeof apiVersion !== "string" || typeof kind !== "string")
    return "apiVersion and kind must be strings";
  let mod;
  try {
    mod = await import(modulePath(apiVersion, kind));
  } catch {
    return `no schema for ${apiVersion} ${kind}`;
  }
  const Model = mod[kind] ?? mod.default;
  if (!Model) return `no model for ${apiVersion} ${kind}`;
  try {
    new Model(doc).validate();
  } catch (e) {
    return e.message;
  }
  return null;
}

async function main(argv) {
  const expectInvalid = argv[0] === "--expect-invalid";
  const files = expectInvalid ? argv.slice(1) : argv;
  if (!files.length) {
    console.error("usage: validate.mjs [--expect-invalid] FILE.yaml...");
    return 2;
  }
  let bad = 0, good = 0;
  for (const file of files) {
    const docs = parseAllDocuments(readFileSync(file, "utf8"));
    for (const d of docs) {
      if (d.errors.length) {
        console.log(`${file}: YAML: ${d.errors[0].message}`);
        bad++;
        continue;
      }
      const doc = d.toJS();
      if (doc === null) continue;  // an empty document (a trailing ---)
      const name = `${file}: ${doc.kind ?? "?"} ${doc.metadata?.name ?? "?"}`;
      const err = await validate(doc);
      if (err) {
        console.log(`${name}: INVALID: ${err}`);
        bad++;
      } else {
        console.log(`${name}: valid`);
        good++;
      }
    }
  }
  console.log(`${good} valid, ${bad} invalid`);
  if (expectInvalid) return good === 0 && bad > 0 ? 0 : 1;
  return bad === 0 && good > 0 ? 0 : 1;
}

process.exitCode = await main(process.argv.slice(2));
