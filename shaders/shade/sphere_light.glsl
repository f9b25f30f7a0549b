// A sphere light of radius R and radiant intensity I (radiance L = I / (pi R^2)), Karis 2013:
//   specular  GGX towards the representative point, the point of the sphere nearest the
//             reflected ray, with alpha widened to alpha' = min(alpha + R / (2 d), 1) and the
//             lobe scaled by (alpha / alpha')^2 so its energy stays that of the light
//   diffuse   the sphere's form factor (Lagarde & de Rousiers 2014, listing 10): above the
//             horizon pi sin^2(sigma) cos(theta) L = I cos(theta) / d^2, a point light's; clipped
//             by the horizon below it
// Inside the sphere (d < R) the surface sees it as from its surface. Needs common/brdf.glsl.

// Irradiance of the sphere / (I / d^2): cos(theta) above the horizon, less as it sets.
float sphere_irradiance_factor(float cos_theta, float sin2_sigma) {
    float c = clamp(cos_theta, -0.9999, 0.9999);
    if (c * c > sin2_sigma) {
        return max(c, 0.0);
    }
    float s2 = max(sin2_sigma, 1e-12);
    float sin_theta = sqrt(1.0 - c * c);
    float x = sqrt(1.0 / s2 - 1.0);
    float y = clamp(-x * c / sin_theta, -1.0, 1.0);
    float root = sin_theta * sqrt(1.0 - y * y);
    float form = (c * acos(y) - x * root) * s2 + atan(root / x);
    return max(form, 0.0) / (PI * s2);
}

// The light reflected towards `v` at a point whose vector to the light's centre is `to_light`.
vec3 sphere_light(
    vec3 to_light, float radius, vec3 intensity, vec3 n, vec3 v, float alpha, vec3 f0,
    vec3 diffuse_albedo, vec3 specular_energy
) {
    float d = sqrt(max(dot(to_light, to_light), 1e-24));
    float dist = max(d, radius);
    vec3 centre = to_light / d;
    vec3 irradiance = intensity / (dist * dist);

    vec3 r = reflect(-v, n);
    vec3 to_ray = dot(to_light, r) * r - to_light;
    vec3 nearest = to_light + to_ray * clamp(radius * inversesqrt(max(dot(to_ray, to_ray), 1e-30)), 0.0, 1.0);
    vec3 l = normalize(nearest);
    float widened = min(alpha + radius / (2.0 * dist), 1.0);
    float energy = (alpha / widened) * (alpha / widened);

    vec3 diffuse;
    vec3 specular;
    vec3 unused;
    brdf_lobes(n, v, centre, f0, diffuse_albedo, alpha, diffuse, unused);
    brdf_lobes(n, v, l, f0, diffuse_albedo, alpha, unused, specular);
    float diffuse_factor = sphere_irradiance_factor(dot(n, centre), radius * radius / (dist * dist));
    float nl = max(dot(n, l), 0.0);
    return (diffuse * diffuse_factor + specular * specular_energy * energy * nl) * irradiance;
}
