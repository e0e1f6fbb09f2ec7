// Loads a GLB written by `ncflow rig` with three.js's own GLTFLoader (the loader a three.js user
// would use), checks the bind pose and plays the clip at its first key; see rig_check.py.
import * as THREE from 'three';
import { GLTFLoader } from 'three/examples/jsm/loaders/GLTFLoader.js';
const b64 = window.GLB_B64;
const bin = Uint8Array.from(atob(b64), c => c.charCodeAt(0)).buffer;
const out = {};
new GLTFLoader().parse(bin, '', (gltf) => {
  let skinned = null;
  gltf.scene.traverse(o => { if (o.isSkinnedMesh) skinned = o; });
  out.skinned = !!skinned;
  out.bones = skinned ? skinned.skeleton.bones.length : 0;
  out.vertices = skinned ? skinned.geometry.attributes.position.count : 0;
  out.clips = gltf.animations.length;
  out.tracks = gltf.animations.length ? gltf.animations[0].tracks.length : 0;
  const scene = new THREE.Scene(); scene.add(gltf.scene);
  scene.updateMatrixWorld(true);
  const v = new THREE.Vector3();
  const pos = skinned.geometry.attributes.position;
  // bind pose: skinned position equals the stored position
  let maxBind = 0;
  for (let i = 0; i < pos.count; i += 7) { v.fromBufferAttribute(pos, i); const w = v.clone(); skinned.applyBoneTransform(i, w); w.applyMatrix4(skinned.matrixWorld); maxBind = Math.max(maxBind, w.distanceTo(v.clone().applyMatrix4(skinned.matrixWorld))); }
  out.maxBindError = maxBind;
  // re-pose: play the clip at t = 0 (the source pose)
  const mixer = new THREE.AnimationMixer(gltf.scene);
  mixer.clipAction(gltf.animations[0]).play(); mixer.setTime(0); scene.updateMatrixWorld(true);
  let moved = 0;
  for (let i = 0; i < pos.count; i += 7) { v.fromBufferAttribute(pos, i); const w = v.clone(); skinned.applyBoneTransform(i, w); moved = Math.max(moved, w.distanceTo(v)); }
  out.maxMoveAtClipStart = moved;
  window.RESULT = out;
}, (e) => { window.RESULT = { error: String(e) }; });
