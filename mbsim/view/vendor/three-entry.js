export {
  WebGLRenderer, Scene, PerspectiveCamera, OrthographicCamera, Group, Mesh, BufferGeometry,
  BufferAttribute, Float32BufferAttribute, MeshStandardMaterial, MeshBasicMaterial, LineBasicMaterial,
  LineSegments, Line, Points, PointsMaterial, AmbientLight, DirectionalLight, HemisphereLight,
  GridHelper, AxesHelper, Color, Vector3, Quaternion, Box3, Sphere, SphereGeometry, CylinderGeometry,
  DoubleSide, MathUtils, SRGBColorSpace, ArrowHelper
} from 'three';
export { OrbitControls } from 'three/examples/jsm/controls/OrbitControls.js';
