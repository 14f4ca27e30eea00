// Offline check of the Kubernetes manifests in deploy/k8s (no cluster needed): every document
// against the Kubernetes API schema (npm kubernetes-models), then featureslam's own rules: the
// ConfigMap's Cyclone profile is configs/dds/kubernetes.xml, unicast, with one peer per
// StatefulSet replica; every server has probes, requests and limits; the GPU variant asks for a
// GPU. Usage: node validate.mjs [FILE.yaml ...] (default: every manifest under deploy/k8s).
import { readFileSync, readdirSync, statSync } from "node:fs";
import { dirname, join, relative } from "node:path";
import { fileURLToPath } from "node:url";
import YAML from "yaml";

const here = dirname(fileURLToPath(import.meta.url));
const k8sDir = dirname(here);
const repo = dirname(dirname(k8sDir));
const errors = [];
const fail = (where, message) => errors.push(`${where}: ${message}`);

function manifests(dir) {
  return readdirSync(dir).flatMap((name) => {
    const path = join(dir, name);
    if (statSync(path).isDirectory()) return name === "validate" ? [] : manifests(path);
    return name.endsWith(".yaml") ? [path] : [];
  });
}

const files = process.argv.length > 2 ? process.argv.slice(2) : manifests(k8sDir);
const docs = [];
for (const file of files) {
  for (const doc of YAML.parseAllDocuments(readFileSync(file, "utf8"))) {
    const where = relative(repo, file);
    if (doc.errors.length) { fail(where, doc.errors.map(String).join("; ")); continue; }
    const obj = doc.toJS();
    if (obj) docs.push({ where, obj });
  }
}

// 1. The Kubernetes schema.
for (const { where, obj } of docs) {
  const at = `${where} ${obj.kind}/${obj.metadata?.name}`;
  let models;
  try {
    models = await import(`kubernetes-models/${obj.apiVersion}`);
  } catch {
    fail(at, `unknown apiVersion ${obj.apiVersion}`);
    continue;
  }
  const Model = models[obj.kind];
  if (!Model) { fail(at, `unknown kind ${obj.kind} in ${obj.apiVersion}`); continue; }
  try {
    new Model(obj).validate();
  } catch (e) {
    fail(at, e.message);
  }
}

// 2. featureslam's rules.
const profile = readFileSync(join(repo, "configs/dds/kubernetes.xml"), "utf8");
const peersOf = (xml) => [...xml.matchAll(/<Peer address="([^"]+)"/g)].map((m) => m[1]);
const configMaps = docs.filter((d) => d.obj.kind === "ConfigMap" && d.obj.metadata.name === "fslam-config");
for (const { where, obj } of configMaps) {
  if (obj.data?.["cyclonedds.xml"] !== profile) fail(where, "cyclonedds.xml differs from configs/dds/kubernetes.xml");
}
if (/<AllowMulticast>\s*true/i.test(profile) || !/<AllowMulticast>\s*false/i.test(profile)) {
  fail("configs/dds/kubernetes.xml", "multicast must be off");
}
for (const { where, obj } of docs.filter((d) => ["StatefulSet", "Deployment"].includes(d.obj.kind))) {
  const at = `${where} ${obj.kind}/${obj.metadata.name}`;
  if (obj.kind === "StatefulSet") {
    const want = Array.from({ length: obj.spec.replicas }, (_, i) => `${obj.spec.serviceName}-${i}.${obj.spec.serviceName}`);
    if (obj.metadata.name !== obj.spec.serviceName) fail(at, "pod names must be the Service's (fslam-<i>.fslam peers)");
    if (JSON.stringify(peersOf(profile)) !== JSON.stringify(want)) {
      fail(at, `Cyclone peers ${peersOf(profile)} must be ${want} (one per replica)`);
    }
    const claims = obj.spec.volumeClaimTemplates?.map((c) => c.metadata.name) ?? [];
    if (!claims.includes("maps")) fail(at, "needs a volume claim template 'maps' for --map-dir");
  }
  for (const c of obj.spec.template.spec.containers) {
    if (!c.readinessProbe || !c.livenessProbe) fail(at, `${c.name}: readiness and liveness probes needed`);
    if (!c.resources?.requests || !c.resources?.limits) fail(at, `${c.name}: resource requests and limits needed`);
    const args = c.command ?? [];
    if (!args.includes("--map-dir") || !args.includes("--health-file")) fail(at, `${c.name}: --map-dir and --health-file needed`);
    if (String(c.image).includes(":gpu") !== Boolean(c.resources?.limits?.["nvidia.com/gpu"])) {
      fail(at, `${c.name}: the gpu image and an nvidia.com/gpu limit go together`);
    }
  }
}
const services = docs.filter((d) => d.obj.kind === "Service");
for (const { where, obj } of services) {
  if (obj.spec.clusterIP !== "None") fail(where, "the Service must be headless (clusterIP: None)");
  if (!obj.spec.publishNotReadyAddresses) fail(where, "publishNotReadyAddresses: pods resolve peers before they are ready");
}

if (errors.length) {
  for (const e of errors) console.error(`FAILED: ${e}`);
  process.exit(1);
}
console.log(`deploy/k8s: ${docs.length} documents in ${files.length} files pass the Kubernetes schema and featureslam's rules`);
