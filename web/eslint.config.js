// ESLint on the UI's sources (`npm run lint`; `make lint` and .ci/run run it where Node is installed).
// typescript-eslint's recommended rules, type-aware (the project's tsconfig.json), on top of ESLint's own.
import js from "@eslint/js";
import tseslint from "typescript-eslint";

export default tseslint.config(
  { ignores: ["dist/", "node_modules/"] },
  js.configs.recommended,
  ...tseslint.configs.recommendedTypeChecked,
  {
    files: ["src/**/*.{ts,tsx}"],
    languageOptions: {
      parserOptions: { projectService: true, tsconfigRootDir: import.meta.dirname },
    },
  },
);
